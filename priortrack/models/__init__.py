"""What filters run on: the protocols (transition model, state space, observation model, filter
model) and the tracking model that composes a pose prior, global motion and translation."""
