"""Experiments: shared metrics, filter presets, tracking runs and the accuracy table, the papers'
reproductions (``reproductions/``) and the benchmarks (``benchmarks/``)."""
