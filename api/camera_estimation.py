"""The wire schema of a camera estimation: how the cameras of a photos-only upload were found,
photo by photo. Written by the engine's estimate (``engine/sfm``), carried in a job's progress,
shown by the job page and ``sparsesplat cameras``."""

from __future__ import annotations

from pydantic import BaseModel, Field


class PhotoPlacement(BaseModel):
    """How one photo of a photos-only upload fared in the camera estimation."""

    name: str
    """The photo's name as uploaded."""
    placed: bool
    """Whether it has a camera (a photo left out is not trained on)."""
    matches: int
    """Verified matches it shares with the other photos (summed over pairs)."""
    points: int = 0
    """Triangulated points it sees (0 when not placed)."""
    error_px: float | None = None
    """Mean reprojection error of those points in this photo, pixels (None when not placed)."""
    rotation_std_deg: float | None = None
    """How firmly its matches fix its orientation: the largest spread, in degrees (one
    standard deviation), of its direction relative to another placed photo's."""
    reason: str | None = None
    """Why it was left out (None when placed)."""


class CameraEstimation(BaseModel):
    """How the cameras of a photos-only upload were estimated (structure from motion)."""

    views: int
    """Photos placed: all of them, or all but those that share no match with the placed ones
    (left out by name in ``photos``, when at least three and half the set are placed)."""
    points: int
    """Sparse points triangulated (``init='sparse'`` starts from them)."""
    reprojection_error_px: float
    """Mean reprojection error of the points, pixels."""
    triangulation_angle_deg: float
    """Median triangulation angle of the points, degrees (the parallax between the photos)."""
    seconds: float
    """Wall time of the estimation."""
    attempt: str
    """The settings that succeeded (``relaxed`` SIFT, ``learned`` matches, ``more features``)."""
    focal: str
    """Where the focal length started: ``given`` (held fixed), ``exif`` or ``guess``."""
    photos: list[PhotoPlacement] = Field(default_factory=list)
    """Each photo in upload order: placed or left out, its matches and its error."""

    def left_out(self) -> list[str]:
        """Names of the photos left out (not trained on), in upload order."""
        return [photo.name for photo in self.photos if not photo.placed]
