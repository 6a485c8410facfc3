"""``sparsesplat scene info``: text and JSON output, sheet, errors."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import pytest

from sparsesplat.engine.commands import scene as scene_cmd
from tests.engine.datasets.synthetic import write_folder_scene


def run_cli(argv: list[str]) -> int:
    parser = argparse.ArgumentParser()
    scene_cmd.add_arguments(parser)
    return scene_cmd.run(parser.parse_args(argv))


def test_info_json_with_prior_and_sheet(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    root = write_folder_scene(tmp_path / "s", count=4, depth=True)
    sheet = tmp_path / "sheet.png"
    code = run_cli(["info", str(root), "--json", "--prior", "user", "--sheet", str(sheet)])
    assert code == 0
    info = json.loads(capsys.readouterr().out)
    assert info["format"] == "folder" and info["image_count"] == 4
    assert info["train_indices"] == [0, 1, 2] and info["test_indices"] == [3]
    assert info["resolution"] == [48, 32]
    assert info["intrinsics"][0]["fx"] == 40.0
    assert [p["depth_median"] for p in info["priors"]] == [3.0, 3.0, 3.0]
    assert all(p["metric"] for p in info["priors"])
    assert sheet.is_file() and info["sheet"] == str(sheet)


def test_info_text_and_error(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    root = write_folder_scene(tmp_path / "s")
    assert run_cli(["info", str(root), "--prior", "none", "--views", "2"]) == 0
    out = capsys.readouterr().out
    assert "scene      s (folder)" in out and "train      [0, 2]" in out
    assert run_cli(["info", str(tmp_path / "missing"), "--prior", "none"]) == 2
    assert "missing: scene folder not found" in capsys.readouterr().err


def test_command_module_does_not_import_torch() -> None:
    import subprocess
    import sys

    code = "import sys, sparsesplat.engine.commands.scene as m; print('torch' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"


@pytest.mark.shared_data
@pytest.mark.parametrize(
    "rel, fmt",
    [
        ("nerf_llff_data/juicebox_table", "llff"),
        ("nerf_synthetic/mic", "blender"),
        ("dtu/dtu_scan24", "dtu"),
        ("instant_ngp/fox", "ngp"),
    ],
)
def test_info_on_shared_scenes(
    shared_data: Path, rel: str, fmt: str, capsys: pytest.CaptureFixture[str]
) -> None:
    assert run_cli(["info", str(shared_data / rel), "--json", "--prior", "none"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["format"] == fmt and len(info["train_indices"]) in (3, 8)
    assert info["image_count"] > len(info["train_indices"]) + len(info["test_indices"]) - 1
