"""Bayesian filters over the priors: particle, unscented, sliding-window MAP; resampling."""
