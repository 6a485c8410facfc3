"""Benchmark entry points, each runnable as ``python -m benchmarks.<name>``."""
