"""Experiment helpers: error metrics and their summaries."""
