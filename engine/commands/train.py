"""``sparsesplat train SCENE_DIR --out DIR``: train one scene locally with its paper protocol.

No torch import at module level (the CLI imports this module to build its parser)."""

from __future__ import annotations

import argparse
import json
import sys
from typing import Any

_FORMAT_PRESET = {"llff": "llff", "dtu": "dtu", "blender": "blender"}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Register the train options."""
    parser.add_argument("scene", help="scene folder (LLFF, Blender, DTU, instant-ngp, upload)")
    parser.add_argument("--out", required=True, help="output folder (checkpoint, metrics, exports)")
    parser.add_argument(
        "--preset", default=None, help="llff | dtu | blender | default (default: from the format)"
    )
    parser.add_argument("--views", type=int, default=None, help="training views (default: paper)")
    parser.add_argument(
        "--iterations",
        type=int,
        default=None,
        help="train this many iterations; fewer than the preset's compress its schedule",
    )
    parser.add_argument("--prior", default=None, help="depth prior setting (default: pydnet)")
    parser.add_argument("--no-depth", action="store_true", help="train without depth losses")
    parser.add_argument("--seed", type=int, default=None, help="random seed")
    parser.add_argument("--device", default="cpu", help="torch device (cpu, cuda)")
    parser.add_argument("--resume", default=None, help="continue from this checkpoint")
    parser.add_argument(
        "--set", action="append", default=[], metavar="FIELD=JSON",
        help="override any TrainConfig field, value as JSON (repeatable)",
    )  # fmt: skip
    parser.add_argument("--quiet", action="store_true", help="do not print progress records")


def _overrides(args: argparse.Namespace) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for item in args.set:
        key, sep, value = item.partition("=")
        if not sep:
            raise SystemExit(f"--set {item!r}: expected FIELD=JSON")
        try:
            out[key] = json.loads(value)
        except json.JSONDecodeError:
            out[key] = value
    if args.seed is not None:
        out["seed"] = args.seed
    if args.prior is not None:
        out["depth_prior"] = args.prior
    if args.no_depth:
        out["depth_prior"] = "none"
    return out


def run(args: argparse.Namespace) -> int:
    """Load the scene, compute priors, train, write ``OUT/metrics.json``; 0 on success."""
    from sparsesplat.engine.datasets import load_scene
    from sparsesplat.engine.errors import EngineError
    from sparsesplat.engine.train import ProgressRecord, Trainer, preset

    try:
        scene = load_scene(args.scene, views=args.views)
        name = args.preset or _FORMAT_PRESET.get(scene.format, "default")
        config = preset(name, **_overrides(args))
        if args.iterations is not None:
            config = config.with_iterations(args.iterations)
        priors = None
        if config.uses_depth:
            from sparsesplat.engine.priors import compute_priors

            priors = compute_priors(scene, config.depth_prior)

        def show(event: Any) -> None:
            if isinstance(event, ProgressRecord) and not args.quiet:
                print(json.dumps(event.to_dict()), flush=True)

        trainer = Trainer(scene, config, priors, args.out, show, args.device, args.resume)
        result = trainer.run()
    except EngineError as exc:
        print(f"sparsesplat train: {exc}", file=sys.stderr)
        return 2
    summary = {k: v for k, v in result.metrics.items()}
    summary["artifacts"] = {k: str(v) for k, v in result.artifacts.items()}
    print(json.dumps(summary, indent=1))
    return 0
