"""Experiment runner for ftorch: protocols, data sets, reports, benchmarks."""
