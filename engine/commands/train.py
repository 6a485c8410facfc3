"""``sparsesplat train SCENE_DIR --out DIR``: train one scene locally.

No torch import at module level (the CLI imports this module to build its parser)."""

from __future__ import annotations

import argparse
import json
import math
import sys
import threading
import time
from pathlib import Path
from typing import Any, TextIO, get_args

from sparsesplat.api.names import PresetName
from sparsesplat.engine.commands.common import (
    CommandError,
    add_set_option,
    check_device,
    guarded,
    json_line,
    prepare_native,
)

PRIOR_KINDS = (
    "pydnet (bundled PyDNet++ monocular depth, the default)",
    "plane_sweep (geometric: photo-consistency between the training views; no network)",
    "onnx:FILE (any MiDaS / DPT / Depth-Anything ONNX export; FILE in the models directory "
    "or a path)",
    "user (the depth maps uploaded with the scene: 'depth' in cameras.json)",
    "none (no depth prior: photometric loss only, same as --no-depth)",
)
"""The ``--prior`` kinds, one line each for ``--help``."""

PRESET_NAMES: tuple[str, ...] = get_args(PresetName)
"""Presets in the order ``--help`` lists them (``api.names.PresetName``, whose names are
``engine.train.config.presets.PRESETS``'s)."""

_PRESET_HELP = {
    "llff": "LLFF-format scenes (poses_bounds.npy): the paper's recipe; where the training "
    "cameras face forward, its recipe for a multi-view-stereo start, from the plane-sweep point "
    "cloud, 3000 iterations; otherwise (an orbit) the random box with opacity decay, 5000 "
    "iterations",
    "dtu": "DTU scans (cameras_sphere.npz): the paper's DTU recipe, 3 views, "
    "opacity decay 0.998; 1500 iterations",
    "blender": "NeRF-synthetic scenes (transforms_train.json): white background, [-1, 1]^3 box, "
    "opacity decay 0.995; 6000 iterations",
    "object": "an object on an empty background (images with alpha, or a plain white/black "
    "backdrop), any unit: the Blender recipe with the init box from the cameras; "
    "6000 iterations",
    "default": "photos of textured surroundings, forward-facing or inward-looking: the LLFF "
    "recipe (forward-facing: from the plane-sweep point cloud, 3000 iterations; otherwise "
    "with opacity decay, 5000 iterations)",
}
# When to use each preset and its default run length. Kept here, not in engine.train.config.presets,
# because this module must not import torch at parse time; tests/cli checks that it names
# exactly the presets that exist, with their PRESET_ITERATIONS and the lengths of their
# LAYOUT_RECIPES.

EPILOG = (
    "presets (chosen from the scene when --preset is not given; the choice and the reason are "
    "printed):\n"
    + "\n".join(f"  {name:8s} {_PRESET_HELP[name]}" for name in PRESET_NAMES)
    + "\n  automatic: the paper's preset for the llff, dtu and blender formats; otherwise "
    "'object' when the images have alpha or a plain white/black backdrop at their borders, "
    "else 'default'.\n"
    "  a preset's default length trains for at most 590 s (on a machine too slow for it the "
    "run ends there, its schedule compressed to fit, and says so); --iterations N trains all "
    "N, --time-budget S trains until S seconds are spent.\n\n"
    "depth priors (--prior):\n" + "\n".join(f"  {kind}" for kind in PRIOR_KINDS) + "\n\n"
    "background: one setting for targets and renders (--set background=white|black|gray|mean|"
    "[r,g,b]; mean: the training photos' mean colour); by default white for images with "
    "alpha, else the format's (black).\n"
    "output: a progress line on stderr and a summary on stdout; --json prints one JSON object "
    "per line instead (kinds: preset, state, record, warning, result).\n"
    "exit codes: 0 done, 1 training failed (diverged, collapsed), 2 bad input, 130 interrupted."
)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Register the train options (presets and prior kinds are listed in the epilog)."""
    parser.formatter_class = argparse.RawDescriptionHelpFormatter
    parser.epilog = EPILOG
    parser.add_argument("scene", help="scene folder (LLFF, Blender, DTU, instant-ngp, upload)")
    parser.add_argument("--out", required=True, help="output folder (checkpoint, metrics, exports)")
    parser.add_argument(
        "--preset",
        default=None,
        choices=PRESET_NAMES,
        help="training recipe (default: chosen from the scene; see below)",
    )
    parser.add_argument(
        "--views", type=int, default=None, help="training views (default: the paper's)"
    )
    parser.add_argument(
        "--iterations",
        type=int,
        default=None,
        help="train this many iterations (default: the preset's, see below); the preset's "
        "6000-iteration reference schedule is compressed or kept to fit",
    )
    parser.add_argument(
        "--time-budget",
        type=float,
        default=None,
        metavar="SECONDS",
        help="train until this many seconds of training are spent instead (a deadline); the "
        "preset's schedule (LR decay, densification, depth starts) follows the elapsed fraction",
    )
    parser.add_argument(
        "--prior",
        default=None,
        metavar="KIND",
        help="depth prior: pydnet (default), plane_sweep, onnx:FILE, user, none (see below)",
    )
    parser.add_argument("--no-depth", action="store_true", help="train without depth losses")
    parser.add_argument("--seed", type=int, default=None, help="random seed")
    parser.add_argument("--device", default="cpu", help="torch device (cpu, cuda)")
    parser.add_argument("--resume", default=None, help="continue from this checkpoint")
    add_set_option(
        parser,
        "override any TrainConfig field by its dotted name, value as JSON (repeatable), "
        "e.g. --set background=white --set photometric.lambda_dssim=0.3 --set depth.soft_start=500",
    )
    parser.add_argument(
        "--json", action="store_true", help="print one JSON object per line (no progress bar)"
    )
    parser.add_argument("--quiet", action="store_true", help="no progress output")


def run_spec(args: argparse.Namespace) -> Any:
    """The :class:`RunSpec` the options ask for (``--set``, ``--seed``, ``--prior``,
    ``--no-depth``, ``--iterations``, ``--time-budget``, ``--preset``)."""
    from sparsesplat.engine.train.config import ConfigError
    from sparsesplat.engine.train.config.overrides import parse_override, resolve
    from sparsesplat.engine.train.run import RunSpec

    overrides: dict[str, Any] = {}
    iterations = args.iterations
    for item in args.set:
        try:
            key, value = parse_override(item)
            name = resolve(key)
        except ConfigError as exc:
            raise CommandError(f"--set {exc}") from None
        if name == "iterations":  # --set iterations=N means --iterations N
            if iterations is not None:
                raise CommandError("give either --iterations or --set iterations=N, not both")
            iterations = value  # its type is checked by the preset
            continue
        overrides[key] = value
    if isinstance(iterations, int) and iterations < 1:
        raise CommandError(f"--iterations must be >= 1, got {iterations}")
    if args.seed is not None:
        overrides["seed"] = args.seed
    if args.prior is not None:
        overrides["depth.prior"] = args.prior
    if args.no_depth:
        overrides["depth.prior"] = "none"
    if args.time_budget is not None:
        if not (math.isfinite(args.time_budget) and args.time_budget > 0):
            raise CommandError(f"--time-budget must be > 0 seconds, got {args.time_budget}")
        if iterations is not None:
            raise CommandError("give either --iterations or --time-budget, not both")
    return RunSpec(args.preset, overrides, iterations, args.time_budget)


def _clock(seconds: float) -> str:
    seconds = max(0, int(seconds))
    h, rest = divmod(seconds, 3600)
    return f"{h}:{rest // 60:02d}:{rest % 60:02d}" if h else f"{rest // 60:02d}:{rest % 60:02d}"


class ProgressLine:
    """The default output: one line on ``stream`` redrawn in place (a TTY) with iteration /
    total, elapsed, estimated remaining and the latest held-out PSNR beside the constant-
    background baseline; on a non-TTY stream, one line per held-out record instead. Under a
    time budget the bar and the time left follow the budget's training seconds; under a time
    limit, whichever of the iterations and the limit's seconds is further along."""

    def __init__(
        self,
        total: int,
        baseline: float | None,
        stream: TextIO,
        budget_s: float | None = None,
        limit_s: float | None = None,
    ) -> None:
        """``baseline``: the PSNR of a constant background image (None: no held-out views);
        ``budget_s``: the run's time budget (None: it runs ``total`` iterations);
        ``limit_s``: its time limit (None: none)."""
        self.total = total
        self.budget_s = budget_s
        self.limit_s = limit_s
        self.trained_s = 0.0
        """The trainer's training seconds so far (what a budget counts)."""
        self.baseline = baseline
        self.stream = stream
        self.tty = stream.isatty()
        self.start = time.monotonic()
        self.start_iteration = 0
        self.iteration = 0
        self.psnr: float | None = None
        self.views = ""
        """Which held-out views the shown PSNR scored ('' when every record scores all)."""
        self._subset = False
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._width = 0

    def text(self) -> str:
        """The current line."""
        done = self.iteration - self.start_iteration
        elapsed = time.monotonic() - self.start
        left = elapsed / done * (self.total - self.iteration) if done > 0 else None
        frac = self.iteration / self.total if self.total else 1.0
        count = f"{self.iteration}/{self.total}"
        if self.budget_s is not None:
            frac = min(self.trained_s / self.budget_s, 1.0)
            left = max(self.budget_s - self.trained_s, 0.0)
            count = f"{self.iteration} it"
        elif self.limit_s is not None:  # the run ends at the limit if that comes first
            frac = max(frac, min(self.trained_s / self.limit_s, 1.0))
            to_limit = max(self.limit_s - self.trained_s, 0.0)
            left = to_limit if left is None else min(left, to_limit)
        bar = "#" * int(20 * frac) + "-" * (20 - int(20 * frac))
        parts = [
            f"{count} [{bar}]",
            f"elapsed {_clock(elapsed)}",
            f"left {_clock(left) if left is not None else '?'}",
        ]
        if self.psnr is not None:
            base = f" (background {self.baseline:.2f})" if self.baseline is not None else ""
            on = f" on {self.views}" if self.views else ""
            parts.append(f"PSNR {self.psnr:.2f} dB{on}{base}")
        return "  ".join(parts)

    def draw(self, final: bool = False) -> None:
        """Redraw the line (TTY only)."""
        if not self.tty:
            return
        line = self.text()
        pad = max(0, self._width - len(line))
        self._width = len(line)
        self.stream.write("\r" + line + " " * pad + ("\n" if final else ""))
        self.stream.flush()

    def record(
        self,
        iteration: int,
        psnr: float | None,
        trained_s: float = 0.0,
        views: tuple[int, int] = (0, 0),
        final: bool = False,
    ) -> None:
        """A held-out record arrived (``trained_s``: its training seconds; ``views``: the
        held-out views it scored, of how many). Records on some of the views say so beside the
        PSNR ('4 of 5 views'), and the final one after them 'all 5 views': the two share the
        last iteration and differ in PSNR."""
        self.iteration = iteration
        self.trained_s = max(self.trained_s, trained_s)
        scored, held_out = views
        if 0 < scored < held_out:
            label = f"{scored} of {held_out} views"
            self._subset = True
        else:
            label = f"all {held_out} views" if final and self._subset else ""
        if psnr is not None:
            self.psnr = psnr
            self.views = label
        if self.tty:
            self.draw()
        else:
            self.stream.write(self.text() + "\n")
            self.stream.flush()

    def follow(self, trainer: Any) -> None:
        """Redraw every half second from ``trainer.iteration`` (a background thread)."""
        self.start_iteration = self.iteration = trainer.iteration
        if not self.tty:
            return

        def loop() -> None:
            while not self._stop.wait(0.5):
                self.iteration = trainer.iteration
                self.trained_s = trainer.elapsed_s
                self.draw()

        self._thread = threading.Thread(target=loop, daemon=True)
        self._thread.start()

    def close(self, iteration: int) -> None:
        """Stop redrawing and end the line."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join()
        self.iteration = iteration
        self.draw(final=True)


def _summary_text(metrics: dict[str, Any], artifacts: dict[str, str]) -> str:
    def fmt(key: str, spec: str) -> str:
        value = metrics.get(key)
        return "n/a" if value is None else format(value, spec)

    base = metrics.get("background_psnr")
    lines = [
        f"PSNR {fmt('psnr', '.2f')} dB"
        + (f" (constant background: {base:.2f} dB)" if base is not None else "")
        + f"  SSIM {fmt('ssim', '.3f')}  LPIPS {fmt('lpips', '.3f')}  AVGE {fmt('avge', '.3f')}",
        f"{metrics.get('iterations')} iterations in {fmt('seconds', '.0f')} s of training"
        + (f" (budget {budget:g} s)" if (budget := metrics.get("time_budget_s")) else "")
        + ", "
        f"{metrics.get('n_gaussians')} Gaussians, preset {metrics.get('preset')}",
    ]
    lines += [f"{kind:12s} {path}" for kind, path in artifacts.items()]
    return "\n".join(lines)


def run(args: argparse.Namespace) -> int:
    """Load the scene, choose the preset, compute priors, train, write ``OUT/metrics.json``.

    0 on success, 2 on bad input (scene, option, config), 1 when training fails."""
    return guarded("train", lambda: _run(args))


def _run(args: argparse.Namespace) -> int:
    from sparsesplat.engine.datasets import load_scene
    from sparsesplat.engine.train import ProgressRecord, StateChange
    from sparsesplat.engine.train.run import RunPlan, build_run

    out = sys.stdout

    def emit(obj: dict[str, Any]) -> None:
        if args.json:
            out.write(json_line(obj) + "\n")
            out.flush()

    device = check_device(args.device)
    spec = run_spec(args)
    scene = load_scene(args.scene, views=args.views)
    talk = not args.json and not args.quiet

    def announce(plan: RunPlan) -> None:
        config = plan.config
        reason = plan.reason or "--preset"
        emit({"kind": "preset", "preset": config.preset, "reason": reason})
        if talk:
            print(f"preset {config.preset}: {reason}", file=sys.stderr, flush=True)
        for note in plan.notes:
            emit({"kind": "note", "note": note})
            if talk:
                print(note, file=sys.stderr, flush=True)
        if config.time_budget_s is not None:
            budget = config.time_budget_s
            emit({"kind": "budget", "seconds": budget, "schedule_iterations": config.iterations})
            if talk:
                print(f"time budget {budget:g} s: training until it is spent", file=sys.stderr)
        prepare_native(device, color=config.color.model == "neural", training=True)

    bar: ProgressLine | None = None

    def show(event: Any) -> None:
        if isinstance(event, ProgressRecord):
            emit(event.to_dict())
            if bar is not None:
                bar.record(
                    event.iteration,
                    event.psnr,
                    event.elapsed_s,
                    (event.views, len(scene.test)),
                    event.final,
                )
        elif isinstance(event, StateChange):
            emit(event.to_dict())

    run = build_run(
        spec,
        scene,
        out_dir=args.out,
        on_progress=show,
        device=device,
        resume_from=args.resume,
        on_plan=announce,
    )
    trainer, config = run.trainer, run.plan.config
    if talk:
        baseline = trainer.background_psnr()
        bar = ProgressLine(
            config.iterations, baseline, sys.stderr, config.time_budget_s, config.time_limit_s
        )
        bar.follow(trainer)
    try:
        result = trainer.run()
    finally:
        if bar is not None:
            bar.close(trainer.iteration)
    artifacts = {k: str(v) for k, v in result.artifacts.items()}
    if trainer.poses is not None and scene.format == "folder":
        # The model is in the refined cameras' frame: write them beside it.
        from sparsesplat.engine.datasets.trained_cameras import (
            TRAINED_CAMERAS_FILE,
            folder_trained_cameras,
        )

        document = folder_trained_cameras(Path(args.scene), scene, trainer.training_cameras())
        path = Path(args.out) / TRAINED_CAMERAS_FILE
        path.write_text(json.dumps(document, indent=1))
        artifacts["cameras"] = str(path)
    for warning in result.metrics.get("warnings", []):
        emit({"kind": "warning", "message": warning})
        if not args.json:
            print(f"sparsesplat train: warning: {warning}", file=sys.stderr, flush=True)
    if args.json:
        emit({"kind": "result", **result.metrics, "artifacts": artifacts})
    else:
        print(_summary_text(result.metrics, artifacts), flush=True)
    return 0
