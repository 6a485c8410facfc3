"""The numerical core of sparsesplat: cameras, scenes, depth priors, rasterizer, trainer, metrics.

The engine imports nothing else of ours (no HTTP, no database, no global state), so it can be
driven from a worker process, a CLI command or a notebook alike.
"""
