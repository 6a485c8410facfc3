"""The SDK installs alone: one pip command, no torch, no FastAPI, one top-level import name."""

from __future__ import annotations

import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
HEAVY = ("torch", "fastapi", "uvicorn", "onnxruntime", "numpy", "scikit-image")


@pytest.fixture(scope="module")
def wheel(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("wheel")
    subprocess.run(
        [sys.executable, "-m", "pip", "wheel", "-q", "--no-deps", "-w", str(out), str(REPO)],
        check=True,
        capture_output=True,
        timeout=300,
    )
    (built,) = out.glob("sparsesplat-*.whl")
    return built


def test_wheel_has_one_top_level_name_and_light_base(wheel: Path) -> None:
    with zipfile.ZipFile(wheel) as z:
        names = z.namelist()
        metadata = next(n for n in names if n.endswith(".dist-info/METADATA"))
        requires = [
            line.split(":", 1)[1].strip()
            for line in z.read(metadata).decode().splitlines()
            if line.startswith("Requires-Dist:")
        ]
    top = {n.split("/")[0] for n in names}
    assert top == {
        "sparsesplat",
        wheel.name.split("-")[0] + "-" + wheel.name.split("-")[1] + ".dist-info",
    }
    assert "sparsesplat/engine/priors/weights/pydnet_pp_matterport.onnx" in names
    base = [r for r in requires if "extra ==" not in r]
    assert base, "base requirements missing"
    for req in base:
        assert not req.lower().startswith(HEAVY), f"base install would pull {req}"
    torch_reqs = [r for r in requires if r.startswith("torch")]
    assert torch_reqs and all(r.startswith("torch==2.13.0") for r in torch_reqs), torch_reqs


def test_sdk_installs_in_a_clean_venv(wheel: Path, tmp_path: Path) -> None:
    venv = tmp_path / "venv"
    subprocess.run([sys.executable, "-m", "venv", str(venv)], check=True, timeout=120)
    py = venv / "bin" / "python"
    subprocess.run(
        [str(py), "-m", "pip", "install", "-q", "--disable-pip-version-check", str(wheel)],
        check=True,
        capture_output=True,
        timeout=300,
    )
    listed = subprocess.run(
        [str(py), "-m", "pip", "list", "--format=freeze"],
        capture_output=True,
        text=True,
        check=True,
    ).stdout.lower()
    for heavy in HEAVY:
        assert f"\n{heavy}==" not in f"\n{listed}", f"{heavy} was installed by the SDK install"
    probe = "import sparsesplat.client as c, sys; c.Client; assert 'torch' not in sys.modules"
    subprocess.run([str(py), "-c", probe], check=True, timeout=60, cwd=tmp_path)
    helped = subprocess.run(
        [str(venv / "bin" / "sparsesplat"), "--help"], capture_output=True, text=True, timeout=60
    )
    assert helped.returncode == 0 and "fetch-weights" in helped.stdout
    # An engine command on the SDK-only install names the extra to add.
    missing = subprocess.run(
        [str(venv / "bin" / "sparsesplat"), "train", "x", "--out", "y"],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert missing.returncode == 3 and "sparsesplat[engine]" in missing.stderr, missing.stderr
