"""Benchmarks (``priortrack bench …``): each times priortrack's code side by side with a reference
in the same run (timing.py holds what they share)."""
