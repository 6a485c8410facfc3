"""Camera estimation from photos alone (structure from motion with pycolmap, lazily imported).

``estimate_cameras(paths)`` returns the cameras in the one camera schema
(:class:`sparsesplat.api.cameras.CamerasFile`, OpenCV camera-to-world, a normalised frame with
near/far and an init box) and the sparse points, or raises :class:`CameraEstimationError`
naming the photos at fault. :mod:`.store` writes and reads both beside the photos.
"""

from sparsesplat.engine.sfm.errors import CameraEstimationError, MissingSfmDependency
from sparsesplat.engine.sfm.estimate import CameraEstimate, estimate_cameras

__all__ = ["CameraEstimate", "CameraEstimationError", "MissingSfmDependency", "estimate_cameras"]
