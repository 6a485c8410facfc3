"""``sparsesplat scene info DIR``: what a scene folder holds, its paper split, its priors.

No torch import at module level (the CLI imports this module to build its parser)."""

from __future__ import annotations

import argparse
import json
import math
import sys
from typing import Any


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Register ``scene info DIR [--json] [--views N] [--prior KIND] [--sheet OUT.png]``."""
    parser.add_argument("action", choices=["info"], help="what to do (info: describe the scene)")
    parser.add_argument("path", help="scene folder (LLFF, Blender, DTU, instant-ngp, upload)")
    parser.add_argument("--json", action="store_true", help="print JSON instead of text")
    parser.add_argument(
        "--views", type=int, default=None, help="training views (default: the paper's)"
    )
    parser.add_argument(
        "--format",
        default=None,
        choices=["llff", "blender", "dtu", "ngp", "folder"],
        help="scene format (default: detected)",
    )
    parser.add_argument(
        "--prior",
        default="pydnet",
        help="depth prior setting: pydnet | plane_sweep | user | none | onnx:NAME=FILE",
    )
    parser.add_argument("--cache-dir", default=None, help="cache computed priors here")
    parser.add_argument(
        "--sheet", default=None, help="write a contact sheet (views | prior | confidence) here"
    )


def _finite(x: float) -> float | None:
    return x if math.isfinite(x) else None


def describe_scene(args: argparse.Namespace) -> dict[str, Any]:
    """Load the scene (and priors) named by ``args`` and return the info record."""
    import torch

    from sparsesplat.engine.datasets import load_scene, source_image_count
    from sparsesplat.engine.datasets.common import (
        background_reason,
        camera_layout,
        has_alpha,
    )
    from sparsesplat.engine.priors import compute_priors
    from sparsesplat.engine.train.config.presets import choose_preset

    scene = load_scene(args.path, views=args.views, format=args.format)
    first = scene.train[0]
    alpha = has_alpha(scene)
    layout = camera_layout([v.camera for v in scene.train + scene.test])
    preset_name, preset_reason = choose_preset(scene)
    info: dict[str, Any] = {
        "name": scene.name,
        "format": scene.format,
        "image_count": source_image_count(args.path, scene.format),
        "resolution": [first.camera.width, first.camera.height],
        "train_indices": scene.train_indices,
        "test_indices": scene.test_indices,
        "train_views": [v.name for v in scene.train],
        "intrinsics": [
            {
                "view": v.name,
                "fx": v.camera.fx,
                "fy": v.camera.fy,
                "cx": v.camera.cx,
                "cy": v.camera.cy,
                "width": v.camera.width,
                "height": v.camera.height,
            }
            for v in scene.train
        ],
        "near": scene.near,
        "far": scene.far,
        "init_box": scene.init_box,
        "background": [float(c) for c in scene.background],
        "background_reason": background_reason(scene),
        "alpha": alpha,
        "layout": {
            "kind": layout.kind,
            "spread_deg": layout.spread_deg,
            "converges": layout.converges,
        },
        "preset": preset_name,
        "preset_reason": preset_reason,
        "masks": any(v.mask is not None for v in scene.train + scene.test),
        "prior": args.prior,
        "priors": [],
    }
    priors = compute_priors(scene, args.prior, cache_dir=args.cache_dir)
    for view, prior in zip(scene.train[: len(priors)], priors, strict=True):
        conf = prior.confidence > 0.5
        vals = prior.depth[conf] if bool(conf.any()) else torch.empty(0)
        stats = (
            torch.quantile(vals.float(), torch.tensor([0.0, 0.5, 1.0])).tolist()
            if vals.numel()
            else [math.nan] * 3
        )
        info["priors"].append(
            {
                "view": view.name,
                "kind": prior.kind,
                "metric": prior.metric,
                "confident_fraction": float(conf.float().mean()),
                "depth_min": _finite(stats[0]),
                "depth_median": _finite(stats[1]),
                "depth_max": _finite(stats[2]),
            }
        )
    if args.sheet:
        from sparsesplat.engine.priors.sheet import contact_sheet

        info["sheet"] = str(contact_sheet(scene, priors, args.sheet))
    return info


def _print_text(info: dict[str, Any]) -> None:
    print(f"scene      {info['name']} ({info['format']}), {info['image_count']} images")
    w, h = info["resolution"]
    print(f"resolution {w}x{h}")
    print(f"train      {info['train_indices']}  ({', '.join(info['train_views'])})")
    print(f"test       {info['test_indices']}")
    print(f"near/far   {info['near']:.4g} / {info['far']:.4g}")
    bg = info["background"]
    print(
        f"background {[round(c, 3) for c in bg]} ({info['background_reason']}; "
        "train --set background=... changes it for targets and renders)"
    )
    lay = info["layout"]
    print(
        f"cameras    {lay['kind']} (view directions within {lay['spread_deg']:.0f}° of their mean)"
    )
    print(f"preset     {info['preset']} ({info['preset_reason']})")
    if info["init_box"]:
        lo, hi = info["init_box"]
        print(f"init box   {[round(x, 3) for x in lo]} .. {[round(x, 3) for x in hi]}")
    for k in info["intrinsics"]:
        print(
            f"camera     {k['view']}: fx {k['fx']:.2f} fy {k['fy']:.2f} "
            f"cx {k['cx']:.2f} cy {k['cy']:.2f} ({k['width']}x{k['height']})"
        )
    for p in info["priors"]:
        med = p["depth_median"]
        print(
            f"prior      {p['view']}: {p['kind']}{' (metric)' if p['metric'] else ''}, "
            f"confident {100 * p['confident_fraction']:.1f}%, median depth "
            f"{'n/a' if med is None else f'{med:.4g}'}"
        )
    if "sheet" in info:
        print(f"sheet      {info['sheet']}")


def run(args: argparse.Namespace) -> int:
    """Print the scene info; typed engine errors become a one-line message and exit code 2."""
    from sparsesplat.engine.errors import EngineError

    try:
        info = describe_scene(args)
    except EngineError as exc:
        print(f"sparsesplat scene: {exc}", file=sys.stderr)
        return 2
    if args.json:
        print(json.dumps(info, indent=1, allow_nan=False))
    else:
        _print_text(info)
    return 0
