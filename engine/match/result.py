"""Keypoints and matches of N photos in plain arrays, and their ``.npz`` form.

Coordinates follow the engine's camera convention (``engine.camera``): pixel (u, v) has its
centre at (u + 0.5, v + 0.5), in the photo's own resolution, whatever size it was matched at.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from sparsesplat.engine.match.errors import MatchError
from sparsesplat.engine.match.settings import MatchSettings

FORMAT_VERSION = 1
"""Version of the ``.npz`` layout (and of the coordinate conventions it stores); part of the
cache key, so a change here never reads an old file."""


@dataclass
class MatchSet:
    """Keypoints per photo and, per pair of photos, which keypoints match.

    Sparse matchers share one keypoint list per photo across all its pairs (so a point seen in
    three photos forms one track). The semi-dense matcher refines a match's position per pair:
    its keypoints are added to the photo's list pair by pair (exact duplicates merged)."""

    keypoints: list[np.ndarray]
    """Per photo, (K_i, 2) float32 pixel coordinates (x, y) with pixel centres at +0.5."""
    matches: dict[tuple[int, int], np.ndarray]
    """(i, j) with i < j -> (M, 2) int32 rows (keypoint index in i, keypoint index in j)."""
    scores: dict[tuple[int, int], np.ndarray]
    """(i, j) -> (M,) float32 confidence of each match (LightGlue's, or the cosine)."""
    sizes: list[tuple[int, int]]
    """Per photo, its (width, height) in pixels."""
    settings: MatchSettings
    """The configuration that produced the matches."""
    seconds: dict[str, float] = field(default_factory=dict)
    """Wall time of the run: 'extract' (features), 'match' (all pairs), 'total'."""

    def pair(self, i: int, j: int) -> tuple[np.ndarray, np.ndarray]:
        """The matched (M, 2) coordinates in photo ``i`` and in photo ``j`` (either order)."""
        a, b = min(i, j), max(i, j)
        rows = self.matches.get((a, b), np.zeros((0, 2), np.int32))
        xa, xb = self.keypoints[a][rows[:, 0]], self.keypoints[b][rows[:, 1]]
        return (xa, xb) if i < j else (xb, xa)

    def count(self, i: int, j: int) -> int:
        """Number of matches between photos ``i`` and ``j``."""
        return len(self.matches.get((min(i, j), max(i, j)), ()))

    def save(self, path: Path) -> Path:
        """Write the set to ``path`` (.npz) atomically; returns ``path``."""
        arrays: dict[str, np.ndarray] = {}
        for i, kp in enumerate(self.keypoints):
            arrays[f"keypoints_{i}"] = np.asarray(kp, np.float32).reshape(-1, 2)
        for (i, j), rows in self.matches.items():
            arrays[f"matches_{i}_{j}"] = np.asarray(rows, np.int32).reshape(-1, 2)
            arrays[f"scores_{i}_{j}"] = np.asarray(self.scores[(i, j)], np.float32)
        meta = {
            "format": FORMAT_VERSION,
            "settings": self.settings.as_json(),
            "sizes": [list(s) for s in self.sizes],
            "seconds": self.seconds,
        }
        arrays["meta"] = np.array(json.dumps(meta))
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_name(path.name + ".tmp.npz")
        np.savez(tmp, **arrays)  # type: ignore[arg-type]
        tmp.replace(path)
        return path

    @classmethod
    def load(cls, path: Path) -> MatchSet:
        """Read a set written by :meth:`save`; MatchError when the file is not one."""
        try:
            with np.load(path, allow_pickle=False) as data:
                meta = json.loads(str(data["meta"]))
                if meta.get("format") != FORMAT_VERSION:
                    raise MatchError(f"{path}: match file format {meta.get('format')}")
                n = len(meta["sizes"])
                keypoints = [np.asarray(data[f"keypoints_{i}"], np.float32) for i in range(n)]
                matches, scores = {}, {}
                for name in data.files:
                    if name.startswith("matches_"):
                        i, j = (int(v) for v in name.split("_")[1:])
                        matches[(i, j)] = np.asarray(data[name], np.int32)
                        scores[(i, j)] = np.asarray(data[f"scores_{i}_{j}"], np.float32)
        except (OSError, KeyError, ValueError) as exc:
            raise MatchError(f"{path}: unreadable match file ({exc})") from exc
        for (i, j), rows in matches.items():
            if len(rows) and (
                rows[:, 0].max() >= len(keypoints[i]) or rows[:, 1].max() >= len(keypoints[j])
            ):
                raise MatchError(f"{path}: matches of pair ({i}, {j}) index missing keypoints")
        return cls(
            keypoints=keypoints,
            matches=matches,
            scores=scores,
            sizes=[(int(w), int(h)) for w, h in meta["sizes"]],
            settings=MatchSettings.from_json(meta["settings"]),
            seconds={k: float(v) for k, v in meta.get("seconds", {}).items()},
        )
