"""Benchmarks record which native kernels ran with the machine (``bench-results/*.json``)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

_SCRIPT = """
import json
import torch
from sparsesplat.engine.bench.common import machine_info
before = machine_info()["kernels"]
from sparsesplat.engine.camera import Camera
from sparsesplat.engine.raster import rasterize
cam = Camera(torch.eye(4), 10.0, 10.0, 4.0, 4.0, 8, 8)
g = torch.tensor([[0.0, 0.0, 3.0]])
rasterize(g, torch.full((1, 3), -1.0), torch.tensor([[1.0, 0, 0, 0]]), torch.zeros(1),
          torch.ones(1, 3), cam)
print(json.dumps({"before": before, "after": machine_info()["kernels"]}))
"""


def _kernels(env_isa: str | None) -> dict[str, dict[str, str]]:
    env = dict(os.environ)
    env.pop("SPARSESPLAT_RASTER_ISA", None)
    if env_isa is not None:
        env["SPARSESPLAT_RASTER_ISA"] = env_isa
    done = subprocess.run(
        [sys.executable, "-c", _SCRIPT],
        env=env,
        cwd=Path(__file__).resolve().parents[2],
        capture_output=True,
        text=True,
    )
    assert done.returncode == 0, done.stderr[-4000:]
    result: dict[str, dict[str, str]] = json.loads(done.stdout.strip().splitlines()[-1])
    return result


def test_machine_info_names_the_kernel_variants_the_process_loaded() -> None:
    """Nothing is listed (or built) before a kernel is used; after one render the rasterizer
    is listed with the variant that ran: the forced AVX2 baseline when the environment asks
    for it, else one of the two the CPU can run."""
    forced = _kernels("avx2")
    assert forced["before"] == {}
    assert forced["after"]["CPU rasterizer"] == "avx2"
    default = _kernels(None)
    assert default["before"] == {}
    assert default["after"]["CPU rasterizer"] in ("avx2", "avx512")
    # A render loads the projection and the rasterizer, not the colour field or the losses.
    assert set(default["after"]) == set(forced["after"]) == {"CPU projection", "CPU rasterizer"}
