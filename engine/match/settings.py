"""What a matcher run is asked to do: the model and its few knobs (part of the cache key)."""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass
from typing import Any

from sparsesplat.engine.match.errors import MatchError

METHODS = ("xfeat-lighterglue", "xfeat-mnn", "xfeat-semidense", "disk-lightglue")
"""The matchers: XFeat sparse keypoints matched by LighterGlue or by mutual nearest
neighbours, XFeat's semi-dense matcher (coarse mutual nearest neighbours refined to sub-pixel
in the first photo of a pair), and DISK keypoints with LightGlue."""


DEFAULT_KEYPOINTS = {
    "xfeat-lighterglue": 2048,
    "xfeat-mnn": 4096,
    "xfeat-semidense": 4096,
    "disk-lightglue": 2048,
}
"""Keypoints per photo when the settings leave it at 0. LightGlue's attention costs the square
of the count: LighterGlue at 4096 keypoints took 7-13 s a pair on one thread against 0.9-1.5
s at 2048 on LLFF (docs/experiments/2026-11-28-matchers.md); the others are linear."""


def resize_factor(longer: int, min_side: int, max_side: int) -> float:
    """How much a photo whose longer side is ``longer`` pixels is scaled before matching:
    shrunk so that side is at most ``max_side``, or enlarged to ``min_side`` when it is
    shorter (0 leaves that bound off)."""
    factor = min(1.0, max_side / longer) if max_side else 1.0
    if min_side and longer < min_side:
        factor = min_side / longer
    return factor


@dataclass(frozen=True)
class MatchSettings:
    """One matcher configuration."""

    method: str = "xfeat-lighterglue"
    """One of :data:`METHODS`."""
    max_keypoints: int = 0
    """Keypoints kept per photo (the strongest); for the semi-dense matcher, the coarse
    features per photo. 0: the method's default (:data:`DEFAULT_KEYPOINTS`)."""
    max_side: int = 1024
    """Photos with a longer side are shrunk to it before matching (coordinates are returned
    in the photo's own pixels); 0 keeps every photo as it is."""
    min_side: int = 800
    """Photos with a shorter longer side are enlarged to it before matching (0: never). XFeat
    describes at 1/8 of the resolution, so small photos give it few, coarse keypoints:
    enlarged to 800 px, NeRF-synthetic's mic (400 px) gave 4.3x the matches within 2 px of the
    epipolar lines, DTU scan24 (400 px) 1.8x, horns (504 px) 1.2x, flower the same, and every
    scene a higher fraction of them (docs/experiments/2026-11-28-matchers.md)."""
    min_confidence: float = 0.1
    """LightGlue's match threshold (matches scoring below it are dropped)."""
    min_cosine: float = 0.82
    """Mutual-nearest-neighbour matching: smallest descriptor cosine similarity kept."""
    min_texture: float = 0.01
    """A keypoint whose 9x9 neighbourhood has a grey-level standard deviation below this
    (on a 0-1 scale) is dropped: a flat patch, e.g. the white or black backdrop of an object
    capture, carries no evidence however confidently it was matched."""

    def __post_init__(self) -> None:
        if self.method not in METHODS:
            raise MatchError(f"unknown matcher {self.method!r}: choose one of {', '.join(METHODS)}")
        if self.max_keypoints != 0 and self.max_keypoints < 8:
            raise MatchError(f"max_keypoints must be 0 (default) or >= 8, got {self.max_keypoints}")
        if self.max_side < 0 or 0 < self.max_side < 32:
            raise MatchError(f"max_side must be 0 (no limit) or at least 32, got {self.max_side}")
        if self.min_side < 0 or (self.max_side and self.min_side > self.max_side):
            raise MatchError(
                f"min_side must be between 0 and max_side ({self.max_side}), got {self.min_side}"
            )
        if not 0.0 <= self.min_confidence < 1.0:
            raise MatchError(f"min_confidence must be in [0, 1), got {self.min_confidence}")
        if not -1.0 <= self.min_cosine < 1.0:
            raise MatchError(f"min_cosine must be in [-1, 1), got {self.min_cosine}")
        if self.min_texture < 0.0:
            raise MatchError(f"min_texture must be >= 0, got {self.min_texture}")

    @property
    def keypoints(self) -> int:
        """The keypoint count in effect (``max_keypoints`` or the method's default)."""
        return self.max_keypoints or DEFAULT_KEYPOINTS[self.method]

    def as_json(self) -> str:
        """The settings as canonical JSON (sorted keys): stored with a result, hashed into
        the cache key."""
        return json.dumps(asdict(self), sort_keys=True)

    @classmethod
    def from_json(cls, text: str) -> MatchSettings:
        """The settings stored by :meth:`as_json`."""
        data: dict[str, Any] = json.loads(text)
        return cls(**data)
