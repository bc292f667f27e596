"""Tracking people in a scene: cross-view association of every camera's 2D people (`association`),
and the scene tracker that keeps each person's identity over time (`scene`)."""
