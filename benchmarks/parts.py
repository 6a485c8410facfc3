"""What each optional training part costs per iteration (``make bench-parts``).

The quality table of a part (``make bench-quality``) says what it adds; this one says what it
costs. A synthetic 3-view scene at 504x378 (a random Gaussian blob rendered as ground truth)
and a fixed model of ``--gaussians`` Gaussians, densification off so the size stays put; every
pass of the LLFF recipe runs (hard depth, soft depth, photometric with the neural field). Each
variant is one part switched on (the same ``set:`` syntax as bench-quality); the variants are
timed in interleaved rounds of ``--iterations`` iterations, so a slow spell of the machine
hits them all alike, and the table gives the median seconds per iteration over the rounds,
its difference to ``base`` and the one-time set-up seconds (building the trainer: dense init
computes its plane-sweep prior there).
"""

from __future__ import annotations

import argparse
import statistics
import time
from typing import Any

from benchmarks.common import machine_info, write_results

DEFAULT_VARIANTS = (
    "base",
    "set:dropout=true",
    "set:init=dense",
    "set:dtu_background=true",
    "set:consistency_weight=0.1",
    "set:near_prune=true",
)
"""``base`` is the LLFF recipe with every optional part off (dropout, the LLFF preset's
default, included); every other variant switches one part on."""


def _overrides(variant: str) -> dict[str, Any]:
    from benchmarks.quality import variant_overrides

    return {} if variant == "base" else variant_overrides(variant)


def build(
    variant: str, gaussians: int, seed: int = 0, size: tuple[int, int] = (504, 378)
) -> tuple[Any, float]:
    """A trainer for ``variant`` past every schedule start, and the seconds it took to build;
    ``size``: (width, height) of the synthetic views."""
    from sparsesplat.engine.synthetic import make_scene
    from sparsesplat.engine.train.run import RunSpec, build_run

    scene, priors = make_scene(seed=seed, width=size[0], height=size[1], n_gaussians=400)
    # Naming the init (the base recipe's own ``auto``: the trainer picks it from the cameras'
    # layout, as every figure of this bench was taken) keeps the run recipe from adding the
    # forward-facing layout recipe (its consistency term, cap, ...): each variant is the LLFF
    # base recipe with one part switched on.
    overrides = {"init": "auto"} | _overrides(variant)
    spec = RunSpec(
        "llff",
        {"init_points": gaussians, "dense_init_points": gaussians, "export": False,
         "eval_interval_s": 0, "densify_until": 0, "clean_iterations": (),
         "near_prune_start": 0, "near_prune_radius": 0.05,
         **({"dropout": False} | overrides)},  # the LLFF preset drops by default
        iterations=10_000,
    )  # fmt: skip
    t0 = time.perf_counter()
    # The synthetic scene's exact depths are the priors, whatever the config's prior kind.
    trainer = build_run(spec, scene, prior_source=lambda _scene, _kind: priors).trainer
    setup = time.perf_counter() - t0
    trainer.iteration = 3500  # past soft_depth_start and depth_smooth_start: every pass runs
    return trainer, setup


def time_round(trainer: Any, iterations: int) -> float:
    """Mean seconds per iteration over ``iterations`` steps of ``trainer``."""
    t0 = time.perf_counter()
    for _ in range(iterations):
        trainer.iteration += 1
        trainer._step()
    return (time.perf_counter() - t0) / iterations


def main() -> None:
    """Print and save the table."""
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--variants", default=",".join(DEFAULT_VARIANTS))
    parser.add_argument("--gaussians", type=int, default=20_000)
    parser.add_argument("--iterations", type=int, default=25, help="iterations per round")
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--threads", type=int, default=None, help="torch threads")
    args = parser.parse_args()
    import torch

    if args.threads:
        torch.set_num_threads(args.threads)
    print(machine_info())
    variants = [v for v in args.variants.split(",") if v]
    trainers, setups = {}, {}
    for v in variants:
        trainers[v], setups[v] = build(v, args.gaussians)
        time_round(trainers[v], 1)  # warm-up: extension load, first allocations
    samples: dict[str, list[float]] = {v: [] for v in variants}
    for _ in range(args.rounds):
        for v in variants:
            samples[v].append(time_round(trainers[v], args.iterations))
    base = statistics.median(samples[variants[0]])
    rows = []
    for v in variants:
        s = statistics.median(samples[v])
        rows.append({
            "variant": v,
            "gaussians": len(trainers[v].gaussians),
            "s_per_iter": round(s, 4),
            "vs_" + variants[0]: round(s - base, 4),
            "setup_s": round(setups[v], 2),
            "threads": torch.get_num_threads(),
        })  # fmt: skip
    cols = ["variant", "gaussians", "s_per_iter", "vs_" + variants[0], "setup_s", "threads"]
    write_results("parts", rows, cols)


if __name__ == "__main__":
    main()
