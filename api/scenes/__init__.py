"""Scene formats on disk, read the same way by the engine and by the torch-free SDK.

Every dataset layout the project reads (LLFF, NeRF-synthetic/Blender, DTU in the NeuS layout,
instant-ngp/nerfstudio ``transforms.json``, and the service's own ``cameras.json`` folder) is
parsed here once: which files a format has (:mod:`.formats`), the paper's train/test splits
(:mod:`.splits`), and each format's cameras as plain float64 matrices in the format's own pose
convention (:mod:`.llff`, :mod:`.transforms`, :mod:`.dtu`). The engine wraps the results into
torch ``Scene`` objects (``engine/datasets``); the SDK packs them into an upload
(``client/scenes.py``).

Only the standard library at import time; NumPy is imported inside the functions that need it
(``poses_bounds.npy``, ``cameras_sphere.npz``, lens undistortion), so the base SDK install
reads the JSON formats without it. Problems raise :class:`SceneFormatError` naming the file.
"""

from sparsesplat.api.scenes.errors import SceneFormatError
from sparsesplat.api.scenes.formats import (
    FORMAT_PRESETS,
    FORMATS,
    IMAGE_SUFFIXES,
    MARKERS,
    PAPER_VIEWS,
    SceneFormat,
    detect_format,
    list_images,
)

__all__ = [
    "FORMATS",
    "FORMAT_PRESETS",
    "IMAGE_SUFFIXES",
    "MARKERS",
    "PAPER_VIEWS",
    "SceneFormat",
    "SceneFormatError",
    "detect_format",
    "list_images",
]
