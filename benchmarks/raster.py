"""``make bench-raster``: CPU rasterizer speed and memory on the synthetic scene.

The scene follows ../shared/docs/cpu-rasterizer.md (seed 0): means uniform in x in +-3.47,
y in +-2.6, z in [3, 7] before an identity camera (504x378, fx=fy=400); sigma log-uniform over
1-8 px at depth 5 with per-axis log-scale jitter N(0, 0.3); randn quaternions; opacity U[0.1, 0.9];
RGB U[0, 1]; black background. Loss = mean(RGB) + 0.1 mean(depth). Each N runs in a fresh
subprocess so its peak RSS (ru_maxrss) is its own.
"""

from __future__ import annotations

import argparse
import json
import math
import resource
import statistics
import subprocess
import sys
import time
from typing import Any

COLUMNS = [
    "n", "width", "height", "threads", "variant", "fwd_ms", "fwd_bwd_ms", "depth_fwd_ms",
    "peak_mb", "pairs_evaluated", "pairs_blended",
]  # fmt: skip
"""Columns of the printed table (the JSON rows carry the same keys)."""


def make_scene(n: int, seed: int = 0) -> dict[str, Any]:
    """The seeded synthetic scene and camera of the benchmark."""
    import torch

    from sparsesplat.engine.camera import Camera

    g = torch.Generator().manual_seed(seed)
    lo = torch.tensor([-3.47, -2.6, 3.0])
    hi = torch.tensor([3.47, 2.6, 7.0])
    means = lo + (hi - lo) * torch.rand(n, 3, generator=g)
    sigma_px = torch.exp(math.log(8.0) * torch.rand(n, generator=g))  # log-uniform 1-8 px
    sigma_world = sigma_px * 5.0 / 400.0
    log_scales = torch.log(sigma_world).unsqueeze(-1) + 0.3 * torch.randn(n, 3, generator=g)
    quats = torch.randn(n, 4, generator=g)
    opacity = 0.1 + 0.8 * torch.rand(n, generator=g)
    logits = torch.log(opacity / (1 - opacity))
    rgb = torch.rand(n, 3, generator=g)
    cam = Camera(torch.eye(4), 400.0, 400.0, 252.0, 189.0, 504, 378)
    return {"means": means, "log_scales": log_scales, "quats": quats, "logits": logits,
            "rgb": rgb, "camera": cam}  # fmt: skip


def _median_ms(fn: Any, repeats: int, warmup: int = 2) -> float:
    """Median wall time of ``fn()`` in milliseconds after ``warmup`` calls."""
    for _ in range(warmup):
        fn()
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append((time.perf_counter() - t0) * 1e3)
    return statistics.median(times)


def run_case(n: int, threads: int, repeats: int) -> dict[str, Any]:
    """Time one N in this process; returns one result row."""
    import torch

    from sparsesplat.engine.raster import rasterize
    from sparsesplat.engine.raster.build import load_extension

    torch.set_num_threads(threads)
    s = make_scene(n)
    params = [s["means"], s["log_scales"], s["quats"], s["logits"], s["rgb"]]
    cam = s["camera"]

    def fwd() -> Any:
        with torch.no_grad():
            return rasterize(params[0], params[1], params[2], params[3], params[4], cam)

    def depth_fwd() -> Any:
        with torch.no_grad():
            return rasterize(params[0], params[1], params[2], params[3], params[4][:, :0], cam)

    def fwd_bwd() -> None:
        ps = [p.detach().requires_grad_(True) for p in params]
        out = rasterize(ps[0], ps[1], ps[2], ps[3], ps[4], cam)
        loss = out.image.mean() + 0.1 * out.depth.mean()
        loss.backward()

    out = fwd()
    row = {
        "n": n, "width": cam.width, "height": cam.height, "threads": threads,
        "variant": load_extension().variant(),
        "fwd_ms": _median_ms(fwd, repeats),
        "fwd_bwd_ms": _median_ms(fwd_bwd, repeats),
        "depth_fwd_ms": _median_ms(depth_fwd, repeats),
        "pairs_evaluated": out.stats["pairs_evaluated"],
        "pairs_blended": out.stats["pairs_blended"],
    }  # fmt: skip
    row["peak_mb"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
    return row


def main(argv: list[str] | None = None) -> int:
    """Run every N in its own subprocess, print the table, write bench-results/raster.json."""
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--n", type=int, nargs="+", default=[10_000, 50_000, 100_000])
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--repeats", type=int, default=7)
    parser.add_argument("--case", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.case:  # child: one N, JSON on the last stdout line
        print(json.dumps(run_case(args.n[0], args.threads, args.repeats)))
        return 0
    from benchmarks.common import write_results

    rows = []
    for n in args.n:
        cmd = [sys.executable, "-m", "benchmarks.raster", "--case", "--n", str(n)]
        cmd += ["--threads", str(args.threads), "--repeats", str(args.repeats)]
        done = subprocess.run(cmd, check=True, capture_output=True, text=True)
        rows.append(json.loads(done.stdout.strip().splitlines()[-1]))
    write_results("raster", rows, COLUMNS)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
