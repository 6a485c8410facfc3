"""``sparsesplat render CHECKPOINT --camera JSON -o OUT.png``: render a trained model.

The camera JSON holds ``fx, fy, cx, cy, width, height`` and either ``world_to_camera`` (4x4,
OpenCV axes, the engine convention) or ``camera_to_world`` (4x4, OpenCV axes). No torch import at
module level."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Register the render options."""
    parser.add_argument("checkpoint", help="checkpoint.pt or a run folder holding one")
    parser.add_argument("--camera", required=True, help="camera JSON file (or inline JSON)")
    parser.add_argument("-o", "--output", required=True, help="output PNG path")
    parser.add_argument("--depth", default=None, help="also write the depth as .npy here")
    parser.add_argument("--device", default="cpu", help="torch device")


def _camera(spec: str) -> Any:
    import torch

    from sparsesplat.engine.camera import Camera
    from sparsesplat.engine.errors import CameraError

    text = Path(spec).read_text() if Path(spec).is_file() else spec
    try:
        d = json.loads(text)
        if "world_to_camera" in d:
            w2c = torch.tensor(d["world_to_camera"], dtype=torch.float32)
        else:
            w2c = torch.linalg.inv(torch.tensor(d["camera_to_world"], dtype=torch.float64)).float()
        return Camera(w2c, float(d["fx"]), float(d["fy"]), float(d["cx"]), float(d["cy"]),
                      int(d["width"]), int(d["height"]))  # fmt: skip
    except (json.JSONDecodeError, KeyError, TypeError, ValueError, RuntimeError) as exc:
        raise CameraError(f"--camera {spec!r}: not a valid camera JSON ({exc})") from exc


def run(args: argparse.Namespace) -> int:
    """Render one view to PNG; 0 on success, 2 on a bad input."""
    import numpy as np
    from PIL import Image

    from sparsesplat.engine.errors import EngineError
    from sparsesplat.engine.train import load_model

    try:
        model = load_model(args.checkpoint, args.device)
        out = model.render(_camera(args.camera))
    except EngineError as exc:
        print(f"sparsesplat render: {exc}", file=sys.stderr)
        return 2
    img = (out.image.clamp(0, 1).permute(1, 2, 0).cpu().numpy() * 255.0 + 0.5).astype(np.uint8)
    Path(args.output).parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(img).save(args.output)
    if args.depth:
        np.save(args.depth, out.depth[0].cpu().numpy())
    print(args.output)
    return 0
