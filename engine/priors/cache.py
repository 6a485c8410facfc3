"""On-disk cache of computed priors: one ``.npz`` per training view, keyed by the prior
setting and the view's pixels and camera, so a changed image or pose never reuses a stale map."""

from __future__ import annotations

import hashlib
from pathlib import Path

import numpy as np
import torch

from sparsesplat.engine.priors.base import PriorDepth
from sparsesplat.engine.scene import View


def view_key(view: View, setting: str) -> str:
    """Stable hash of the prior ``setting``, the view's image bytes and its camera."""
    h = hashlib.sha1(setting.encode())
    h.update(view.image.detach().cpu().float().contiguous().numpy().tobytes())
    cam = view.camera
    h.update(cam.world_to_camera.detach().cpu().double().numpy().tobytes())
    h.update(np.array([cam.fx, cam.fy, cam.cx, cam.cy, cam.width, cam.height]).tobytes())
    return h.hexdigest()[:16]


def cache_path(cache_dir: Path, view: View, setting: str) -> Path:
    """Where the prior of ``view`` under ``setting`` is cached."""
    safe = "".join(ch if ch.isalnum() or ch in "-_" else "_" for ch in view.name)
    return Path(cache_dir) / f"prior_{safe}_{view_key(view, setting)}.npz"


def load_cached(path: Path) -> PriorDepth | None:
    """The cached prior at ``path``, or None when absent or unreadable (then recomputed)."""
    if not path.is_file():
        return None
    try:
        with np.load(path, allow_pickle=False) as data:
            return PriorDepth(
                torch.from_numpy(data["depth"].astype(np.float32)),
                torch.from_numpy(data["confidence"].astype(np.float32)),
                bool(data["metric"]),
                str(data["kind"]),
            )
    except (OSError, ValueError, KeyError):
        return None


def save_cached(path: Path, prior: PriorDepth) -> None:
    """Write ``prior`` to ``path`` atomically (temp file + rename)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp.npz")
    np.savez_compressed(
        tmp,
        depth=prior.depth.cpu().numpy(),
        confidence=prior.confidence.cpu().numpy(),
        metric=np.array(prior.metric),
        kind=np.array(prior.kind),
    )
    tmp.replace(path)
