"""Benchmark entry points, each runnable as ``python -m sparsesplat.engine.bench.<name>``."""
