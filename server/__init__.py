"""The HTTP service (FastAPI). Imports ``sparsesplat.api`` only; never torch."""
