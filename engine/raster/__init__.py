"""Differentiable Gaussian rasterization: one function, three backends.

``rasterize`` dispatches to the native C++/OpenMP kernel for CPU tensors, gsplat for CUDA
tensors, or the dense float64 reference (``backend="reference"``, the test oracle).
"""

from sparsesplat.engine.raster.api import BACKENDS, rasterize
from sparsesplat.engine.raster.types import RasterOutput

__all__ = ["BACKENDS", "RasterOutput", "rasterize"]
