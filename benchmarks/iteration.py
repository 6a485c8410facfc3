"""Seconds per training iteration at 504x378, split by stage (``make bench-iteration``).

A synthetic 3-view scene (random Gaussian blob rendered as ground truth) and a model of ~20k and
~50k Gaussians. Every pass runs (hard depth, soft depth, photometric with the neural field); the
stages are: the two depth passes (render + loss + backward + Adam step; the soft one, fused into
the photometric pass, is its loss only), the neural field forward and backward, the photometric
render forward, its loss, the warp-consistency term where the config has it, the raster+loss
backward, densification bookkeeping and the final Adam step. Densification itself is disabled
so N stays fixed.

The random box is a heavier workload than a trained model of the same size (larger footprints,
more Gaussians blended per pixel). ``--trained SCENE CHECKPOINT`` adds a row that continues a
real run instead: the scene, and the model and optimizer state a ``sparsesplat train SCENE
--out RUN`` run left in ``RUN/checkpoint.pt``, with that scene's plain ``train`` config.

A second table times the neural colour field alone (forward, and backward to the centres and all
field parameters) with the native kernels and with the torch reference hash grid + SH
(``--field-backends``), at the same sizes.

``--device cuda`` times the iteration tables on the GPU (gsplat's rasterizer, the torch hash
grid): the totals are synchronized, wall seconds of whole iterations; the stage columns are
the host's seconds per stage, which on a GPU measure launches rather than the kernels' work
(the field and loss tables time the CPU kernels whatever the device).

A third table times the photometric loss L1 + 0.2 * D-SSIM alone (forward and backward to the
rendered image, target statistics precomputed as in training) with the native fused kernel and
with the torch reference (``--loss-backends``), at the iteration's image size.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

from benchmarks.common import machine_info, write_results
from sparsesplat.engine.commands.common import add_set_option

if TYPE_CHECKING:
    from sparsesplat.engine.train import Trainer


def _synchronize(device: str) -> None:
    """Wait for the GPU's queued work when ``device`` is one (a CPU step is done on return)."""
    if device.startswith("cuda"):
        import torch

        torch.cuda.synchronize()


def _time_steps(t: Trainer, iterations: int, device: str = "cpu") -> dict[str, float]:
    """Mean seconds per stage (``t``'s profile timings) and in total over ``iterations`` steps
    of ``t`` after warm-up steps (one on the CPU; three on a GPU, whose first steps also pick
    kernels and grow its memory pool), with denormals flushed as ``Trainer.run`` does."""
    from sparsesplat.engine.denormals import flush_denormals

    with flush_denormals():
        for _ in range(3 if device.startswith("cuda") else 1):
            t.iteration += 1
            t._step()
        _synchronize(device)
        t.timings.clear()
        t0 = time.perf_counter()
        for _ in range(iterations):
            t.iteration += 1
            t._step()
        _synchronize(device)
        total = (time.perf_counter() - t0) / iterations
    row = {k: v / iterations for k, v in t.timings.items()}
    row.update(gaussians=len(t.gaussians), total_s=total)
    return row


def measure(
    n: int,
    iterations: int,
    width: int = 504,
    height: int = 378,
    overrides: dict[str, Any] | None = None,
    device: str = "cpu",
) -> dict[str, float]:
    """Mean seconds per stage over ``iterations`` timed iterations (after the warm-up) of the
    ``llff`` preset on ``device``, with dotted-field ``overrides`` (``--set``) on top."""
    from sparsesplat.engine.malloc import keep_freed_memory
    from sparsesplat.engine.synthetic import make_scene
    from sparsesplat.engine.train.run import RunSpec, build_run

    keep_freed_memory()  # as Trainer.run does
    scene, priors = make_scene(seed=0, width=width, height=height, n_gaussians=400)
    # The random box whatever the preset's init: the workload every figure of this bench was
    # taken on (a dense init puts the points on the surface, with smaller footprints). Naming
    # the init keeps the preset's base recipe whatever the synthetic cameras' layout.
    spec = RunSpec(
        "llff",
        {"init": "random", "init_points": n, "profile": True, "export": False,
         "eval_interval_s": 0, "densify_until": 0, "clean_iterations": (), **(overrides or {})},
        iterations=10_000,
    )  # fmt: skip
    # The synthetic scene's exact depths are the priors, whatever the config's prior kind.
    run = build_run(spec, scene, prior_source=lambda _scene, _kind: priors, device=device)
    t = run.trainer
    t.iteration = 3500  # past soft_depth_start and depth_smooth_start: every pass runs
    return _time_steps(t, iterations, device)


def measure_trained(
    scene_dir: str,
    checkpoint: str,
    iterations: int,
    overrides: dict[str, Any] | None = None,
    device: str = "cpu",
) -> dict[str, float]:
    """Mean seconds per stage of ``iterations`` iterations (after the warm-up) continuing a real
    run: the scene at ``scene_dir`` and the model, field and optimizer state of ``checkpoint``
    (a ``sparsesplat train --out RUN`` run's ``RUN/checkpoint.pt``), with the plain ``train``
    config for that scene (its preset and layout recipe) plus ``overrides``. Densification and
    evaluation are off so the Gaussian count stays the checkpoint's; the iterations continue
    from the checkpoint's own, where the run's last iterations left every pass."""
    from sparsesplat.engine.datasets import load_scene
    from sparsesplat.engine.malloc import keep_freed_memory
    from sparsesplat.engine.train.run import RunSpec, build_run

    keep_freed_memory()
    scene = load_scene(scene_dir)
    spec = RunSpec(
        overrides={
            "record.profile": True, "record.export": False, "record.eval_interval_s": 0,
            "densify.until": 0, "densify.clean_iterations": (), **(overrides or {}),
        }
    )  # fmt: skip
    run = build_run(spec, scene, resume_from=checkpoint, device=device)
    return _time_steps(run.trainer, iterations, device)


def measure_field(n: int, backend: str, iterations: int) -> dict[str, float | int | str]:
    """Mean seconds of the colour field's forward and backward for ``n`` random centres."""
    import torch

    from sparsesplat.engine.color.models import NeuralColor

    g = torch.Generator().manual_seed(0)
    points = torch.rand(n, 3, generator=g) * 4 - 2
    color = NeuralColor.create(points, g)
    color.field.grid.backend = backend
    means = points.clone().requires_grad_(True)
    camera = torch.tensor([0.1, 0.2, -5.0])
    upstream = torch.rand(n, 3, generator=g) * 1e-3
    fwd = bwd = 0.0
    for i in range(iterations + 1):  # the first is a warm-up (extension load, allocations)
        means.grad = None
        color.field.zero_grad(set_to_none=True)
        t0 = time.perf_counter()
        out = color.field(means, camera)
        t1 = time.perf_counter()
        out.backward(upstream)
        t2 = time.perf_counter()
        if i:
            fwd, bwd = fwd + (t1 - t0), bwd + (t2 - t1)
    return {"gaussians": n, "backend": backend, "fwd_s": fwd / iterations,
            "bwd_s": bwd / iterations}  # fmt: skip


def measure_photometric(
    backend: str, iterations: int, width: int = 504, height: int = 378
) -> dict[str, float | int | str]:
    """Mean seconds of the photometric loss's forward and backward on a ``width`` x ``height``
    RGB image with ``backend`` ('native' or 'torch', via $SPARSESPLAT_PHOTOMETRIC)."""
    import os

    import torch

    from sparsesplat.engine.losses import SSIMTarget, photometric_loss
    from sparsesplat.engine.photometric.native import BACKEND_ENV

    g = torch.Generator().manual_seed(0)
    target = torch.rand(3, height, width, generator=g)
    image = (target + 0.1 * torch.randn(3, height, width, generator=g)).clamp(0, 1)
    stats = SSIMTarget(target)
    previous = os.environ.get(BACKEND_ENV)
    os.environ[BACKEND_ENV] = backend
    fwd = bwd = 0.0
    try:
        for i in range(iterations + 1):  # the first is a warm-up (extension load, allocations)
            pred = image.clone().requires_grad_(True)
            t0 = time.perf_counter()
            loss = photometric_loss(pred, target, 0.2, stats)
            t1 = time.perf_counter()
            loss.backward()
            t2 = time.perf_counter()
            if i:
                fwd, bwd = fwd + (t1 - t0), bwd + (t2 - t1)
    finally:
        if previous is None:
            os.environ.pop(BACKEND_ENV, None)
        else:
            os.environ[BACKEND_ENV] = previous
    return {"size": f"{width}x{height}", "backend": backend, "fwd_s": fwd / iterations,
            "bwd_s": bwd / iterations, "total_s": (fwd + bwd) / iterations}  # fmt: skip


def _rounded(row: dict[str, float]) -> dict[str, Any]:
    """The row with its float figures rounded to 4 decimals, for the table."""
    return {k: round(v, 4) if isinstance(v, float) else v for k, v in row.items()}


def main() -> None:
    """Print and save the table."""
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--iterations", type=int, default=5)
    parser.add_argument("--sizes", type=int, nargs="+", default=[20_000, 50_000])
    parser.add_argument(
        "--field-backends", nargs="*", default=["native", "torch"], choices=["native", "torch"],
        help="hash-grid backends for the field-only table (none: skip it)",
    )  # fmt: skip
    parser.add_argument(
        "--loss-backends", nargs="*", default=["native", "torch"], choices=["native", "torch"],
        help="photometric loss implementations for the loss-only table (none: skip it)",
    )  # fmt: skip
    parser.add_argument(
        "--no-iteration", action="store_true", help="only the field and loss tables"
    )
    add_set_option(
        parser,
        "override a TrainConfig field of the timed iteration (repeatable), e.g. to time "
        "the reference's choice: --set depth.hard_downscale=1",
    )
    parser.add_argument(
        "--trained", nargs=2, metavar=("SCENE", "CHECKPOINT"),
        help="also time iterations continuing a real run: the scene folder and the "
        "checkpoint.pt of a `sparsesplat train SCENE --out RUN` run on it (a trained model's "
        "footprints and depth complexity, in place of the random box's)",
    )  # fmt: skip
    parser.add_argument(
        "--device", default="cpu",
        help="torch device of the iteration tables (cpu, cuda); synchronized totals on a GPU",
    )  # fmt: skip
    args = parser.parse_args()
    from sparsesplat.engine.train.config.overrides import parse_override

    overrides = dict(parse_override(item) for item in args.set)
    print(machine_info())
    if args.field_backends:
        field_rows = [
            measure_field(n, b, args.iterations) for n in args.sizes for b in args.field_backends
        ]
        for fr in field_rows:
            fr["fwd_s"], fr["bwd_s"] = round(float(fr["fwd_s"]), 4), round(float(fr["bwd_s"]), 4)
        write_results("iteration_field", field_rows, ["gaussians", "backend", "fwd_s", "bwd_s"])
    if args.loss_backends:
        loss_rows = [measure_photometric(b, args.iterations) for b in args.loss_backends]
        for lr in loss_rows:
            for key in ("fwd_s", "bwd_s", "total_s"):
                lr[key] = round(float(lr[key]), 5)
        write_results(
            "iteration_losses", loss_rows, ["size", "backend", "fwd_s", "bwd_s", "total_s"]
        )
    if args.no_iteration:
        return
    rows = []
    for n in args.sizes:
        r = measure(n, args.iterations, overrides=overrides, device=args.device)
        rows.append({"model": "random box"} | _rounded(r))
    if args.trained:
        scene_dir, checkpoint = args.trained
        r = measure_trained(scene_dir, checkpoint, args.iterations, overrides, args.device)
        rows.append({"model": f"trained {Path(scene_dir).name}"} | _rounded(r))
    cols = ["model", "gaussians", "total_s", "hard_depth", "soft_depth", "neural_fwd",
            "photo_render", "losses", "consistency", "photo_backward", "neural_bwd",
            "optimizer", "setup"]  # fmt: skip
    write_results("iteration", rows, cols)


if __name__ == "__main__":
    main()
