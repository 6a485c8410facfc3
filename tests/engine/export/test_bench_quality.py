"""The quality benchmark harness (no training): discovery, variants, schedule, resume."""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import pytest

import sparsesplat.engine.datasets as datasets
from sparsesplat.engine.bench import quality
from sparsesplat.engine.train import preset


def _make_scenes(root: Path) -> None:
    (root / "llff" / "a").mkdir(parents=True)
    (root / "llff" / "a" / "poses_bounds.npy").write_bytes(b"")
    (root / "dtu" / "b").mkdir(parents=True)
    (root / "dtu" / "b" / "cameras_sphere.npz").write_bytes(b"")
    (root / "notes").mkdir()
    (root / "notes" / "readme.txt").write_text("not a scene")


def test_find_scenes(tmp_path: Path) -> None:
    _make_scenes(tmp_path)
    assert quality.find_scenes([tmp_path]) == [tmp_path / "dtu" / "b", tmp_path / "llff" / "a"]
    assert quality.find_scenes([tmp_path / "llff" / "a"]) == [tmp_path / "llff" / "a"]


def test_variants() -> None:
    base = preset("dtu")
    assert quality.variant_config(base, "full") == base
    assert not quality.variant_config(base, "no_depth").uses_depth
    assert quality.variant_config(base, "prior:plane_sweep").depth_prior == "plane_sweep"
    with pytest.raises(SystemExit, match="unknown variant"):
        quality.variant_config(base, "bogus")


def test_resume_skips_finished_and_reuses_identical_configs(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    _make_scenes(tmp_path / "data")
    calls: list[tuple[str, str]] = []

    def fake_load(path: Path, views: int | None = None, downscale: int = 1) -> Any:
        fmt = "llff" if path.parent.name == "llff" else "dtu"
        return SimpleNamespace(name=path.name, format=fmt, train=[0, 1, 2])

    def fake_entry(scene_path: Path, scene: Any, variant: str, config: Any, *rest: Any) -> dict:
        calls.append((scene.name, variant))
        row = {"scene": scene.name, "variant": variant, "views": 3}
        row |= {"iterations": config.iterations, "psnr": 20.0, "prior": config.depth_prior}
        if scene.name == "b" and variant == "no_depth":
            row["error"] = "TrainingDiverged: boom"
        return row

    monkeypatch.setattr(datasets, "load_scene", fake_load)
    monkeypatch.setattr(quality, "run_entry", fake_entry)
    out = tmp_path / "quality.json"
    parser = argparse.ArgumentParser()
    quality.add_arguments(parser)
    argv = [str(tmp_path / "data"), "--out", str(out), "--iterations", "10"]
    argv += ["--variants", "full,no_depth,prior:pydnet"]
    assert quality.run(parser.parse_args(argv)) == 1  # one entry failed
    # full and prior:pydnet share one configuration (pydnet is the presets' default prior)
    assert sorted(calls) == sorted(
        [("a", "full"), ("a", "no_depth"), ("b", "full"), ("b", "no_depth")]
    )
    rows = json.loads(out.read_text())["rows"]
    assert len(rows) == 6
    reused = [r for r in rows if r["variant"] == "prior:pydnet"]
    assert all(r.get("same_run_as") == "full" for r in reused)

    calls.clear()
    assert quality.run(parser.parse_args(argv)) == 1  # the failed entry is retried, fails again
    assert calls == [("b", "no_depth")]
    assert len(json.loads(out.read_text())["rows"]) == 6
