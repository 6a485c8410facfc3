"""Tiny synthetic scenes written to a temporary folder (the service upload layout)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
from PIL import Image

from sparsesplat.engine.train import TrainConfig, preset


def look_at_c2w(eye: np.ndarray, target: np.ndarray) -> np.ndarray:
    """OpenCV camera-to-world looking from ``eye`` at ``target`` (world +y is down)."""
    fwd = target - eye
    fwd /= np.linalg.norm(fwd)
    right = np.cross(fwd, np.array([0.0, -1.0, 0.0]))
    right /= np.linalg.norm(right)
    down = np.cross(fwd, right)
    c2w = np.eye(4)
    c2w[:3, 0], c2w[:3, 1], c2w[:3, 2], c2w[:3, 3] = right, down, fwd, eye
    return c2w


def write_folder_scene(
    root: Path, count: int = 4, size: tuple[int, int] = (48, 32), depth: bool = False
) -> Path:
    """Write ``count`` random-texture views on a small arc plus ``cameras.json``."""
    root.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(0)
    w, h = size
    frames = []
    for i in range(count):
        angle = -0.3 + 0.6 * i / max(1, count - 1)
        eye = np.array([3.0 * np.sin(angle), 0.0, -3.0 * np.cos(angle)])
        c2w = look_at_c2w(eye, np.zeros(3))
        img = (rng.random((h, w, 3)) * 255).astype(np.uint8)
        Image.fromarray(img).save(root / f"view_{i}.png")
        frame = {
            "image": f"view_{i}.png",
            "matrix": c2w.tolist(),
            "fx": 40.0,
            "fy": 40.0,
            "cx": w / 2,
            "cy": h / 2,
            "width": w,
            "height": h,
            "split": "test" if i == count - 1 else "train",
        }
        if depth:
            np.save(root / f"view_{i}_depth.npy", np.full((h, w), 3.0, dtype=np.float32))
            frame["depth"] = f"view_{i}_depth.npy"
        frames.append(frame)
    meta = {"convention": "opencv", "pose": "camera_to_world", "frames": frames}
    (root / "cameras.json").write_text(json.dumps(meta))
    return root


def smoke_preset(name: str, iterations: int, **overrides: Any) -> TrainConfig:
    """Preset ``name`` at smoke scale for ``iterations``: no depth prior, a small hash grid, no
    evaluation, LPIPS or export; ``overrides`` on top."""
    return preset(
        name,
        depth_prior="none",
        hash_log2_size=14,
        eval_interval_s=0,
        eval_lpips=False,
        export=False,
        **overrides,
    ).with_iterations(iterations)
