"""Benchmarks record which native kernels ran with the machine (``bench-results/*.json``)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from benchmarks import common
from benchmarks.common import RESULTS_DIR_ENV, cpu_identity, write_results

_SCRIPT = """
import json
import torch
from benchmarks.common import machine_info
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


_CPUINFO = """processor\t: 0
vendor_id\t: AuthenticAMD
cpu family\t: 25
model\t\t: 17
model name\t: AMD EPYC
stepping\t: 1
flags\t\t: fpu sse avx avx2 avx512f avx512bw avx512_bf16

processor\t: 1
vendor_id\t: GenuineIntel
cpu family\t: 6
model\t\t: 143
flags\t\t: fpu avx2 amx_tile
"""


def test_cpu_identity_tells_generations_apart_from_the_first_processor() -> None:
    """A hypervisor's bare "AMD EPYC" model name gets family, model, stepping and the ISA flags
    the kernels choose by, read from the first processor's block only."""
    ident = cpu_identity(_CPUINFO)
    assert ident == {
        "vendor": "AuthenticAMD",
        "family": 25,
        "model": 17,
        "stepping": 1,
        "isa": ["avx2", "avx512f", "avx512_bf16"],
    }
    assert cpu_identity("") == {}


def test_bench_header_names_the_cpu_generation(
    capsys: pytest.CaptureFixture[str], tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The table's header line carries family and model when the machine reports them, and
    the results file keeps the whole identity."""
    monkeypatch.setenv(RESULTS_DIR_ENV, str(tmp_path))
    monkeypatch.setattr(
        common,
        "machine_info",
        lambda: {
            "cpu": "AMD EPYC",
            "cpu_id": cpu_identity(_CPUINFO),
            "l3_cache": "32768K",
            "cores": 2,
            "torch": "2.13.0",
            "kernels": {},
        },
    )
    path = write_results("probe", [{"a": 1.0}], ["a"])
    header = capsys.readouterr().out.splitlines()[0]
    assert header == "# probe on AMD EPYC (family 25 model 17, 2 cores, torch 2.13.0)"
    saved = json.loads(path.read_text())["machine"]
    assert saved["cpu_id"]["model"] == 17 and saved["l3_cache"] == "32768K"
