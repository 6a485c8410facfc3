"""The quality benchmark harness (no training): discovery, variants, schedule, resume."""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import pytest

import sparsesplat.engine.datasets as datasets
from benchmarks import quality
from sparsesplat.engine.synthetic import make_cameras
from sparsesplat.engine.train import preset
from sparsesplat.engine.train.run import plan_run


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
    assert quality.variant_config("dtu", "full") == base
    assert not quality.variant_config("dtu", "no_depth").uses_depth
    assert quality.variant_config("dtu", "prior:plane_sweep").depth.prior == "plane_sweep"
    assert quality.variant_config("dtu", "full", seed=2).seed == 2
    with pytest.raises(SystemExit, match="unknown variant"):
        quality.variant_config("dtu", "bogus")


def test_resume_skips_finished_and_reuses_identical_configs(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    _make_scenes(tmp_path / "data")
    calls: list[tuple[str, str]] = []

    def fake_load(path: Path, views: int | None = None, downscale: int = 1) -> Any:
        fmt = "llff" if path.parent.name == "llff" else "dtu"
        # training views need cameras: the bench reads their layout for the preset's recipe
        train = [SimpleNamespace(camera=c) for c in make_cameras(3, 8, 6)]
        return SimpleNamespace(name=path.name, format=fmt, train=train, pose_std_deg=None)

    def fake_entry(scene_path: Path, scene: Any, variant: str, spec: Any, *rest: Any) -> dict:
        calls.append((scene.name, variant))
        config = plan_run(spec, scene).config  # the run recipe's config, as run_entry trains
        row = {"scene": scene.name, "variant": variant, "views": 3}
        row |= {"iterations": config.iterations, "psnr": 20.0, "prior": config.depth.prior}
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


def test_set_variants_override_validated_fields() -> None:
    base = preset("llff")
    config = quality.variant_config("llff", 'set:lambda_dssim=0.3+color.model="sh"')
    assert (config.photometric.lambda_dssim, config.color.model) == (0.3, "sh")
    assert config.iterations == base.iterations and config.preset == "llff"
    from sparsesplat.engine.train.config import ConfigError

    with pytest.raises(ConfigError, match="lambda_dsim"):
        quality.variant_config("llff", "set:lambda_dsim=0.3")
    with pytest.raises(SystemExit, match="FIELD=JSON"):
        quality.variant_config("llff", "set:lambda_dssim")


def test_best_error_is_the_first_time_the_best_psnr_was_reached() -> None:
    records = [
        {"psnr": 10.0, "elapsed_s": 0.0},
        {"psnr": 19.0, "elapsed_s": 30.0},
        {"psnr": None, "elapsed_s": 40.0},
        {"psnr": 19.0, "elapsed_s": 60.0},
        {"psnr": 18.5, "elapsed_s": 90.0},
    ]
    assert quality.best_error(records) == (19.0, 30.0)
    assert quality.best_error([]) == (None, None)


def test_summary_is_mean_and_sample_std_over_seeds(tmp_path: Path) -> None:
    def row(seed: int, psnr: float, **extra: Any) -> dict[str, Any]:
        base = {"scene": "a", "variant": "full", "views": 3, "iterations": 10, "seed": seed}
        return base | {"psnr": psnr} | extra

    rows = [row(0, 18.0), row(1, 20.0), row(2, 22.0), row(3, 99.0, error="boom")]
    (summary,) = quality.summarize(rows)
    assert summary["seeds"] == "0,1,2"
    assert summary["psnr"] == "20 ± 2"  # sample std of 18, 20, 22 is 2
    assert summary["psnr_values"] == [18.0, 20.0, 22.0]
    # merging two partial result files (two sweeps run side by side) keeps every seed
    for i, part in enumerate((rows[:2], rows[2:3])):
        (tmp_path / f"part{i}.json").write_text(json.dumps({"rows": part}))
    out = tmp_path / "merged.json"
    assert quality.merge([tmp_path / "part0.json", tmp_path / "part1.json"], out) == 0
    merged = json.loads(out.read_text())
    assert sorted(r["seed"] for r in merged["rows"]) == [0, 1, 2]
    assert merged["summary"][0]["psnr"] == "20 ± 2"


def test_iters_variant_compresses_the_reference_schedule_and_wins_over_iterations() -> None:
    reference = preset("llff", iterations=6000)
    for iterations in (None, 1000):
        short = quality.variant_config("llff", "iters:3000", iterations=iterations)
        assert short.iterations == 3000
        assert short.densify.until == reference.densify.until // 2
        assert short.depth.soft_start == reference.depth.soft_start // 2
    assert quality.variant_config("llff", "full", iterations=1000).iterations == 1000
    with pytest.raises(SystemExit, match="iters:N"):
        quality.variant_config("llff", "iters:many")


def test_per_view_angle_is_the_smallest_optical_axis_angle_to_a_training_camera() -> None:
    import math

    import torch

    from benchmarks import per_view
    from sparsesplat.engine.camera import Camera

    def turned(degrees: float) -> Camera:  # a camera yawed about the world y axis
        a = math.radians(degrees)
        w2c = torch.eye(4, dtype=torch.float64)
        w2c[:3, :3] = torch.tensor(
            [[math.cos(a), 0.0, -math.sin(a)], [0.0, 1.0, 0.0], [math.sin(a), 0.0, math.cos(a)]],
            dtype=torch.float64,
        )
        return Camera(w2c, 10.0, 10.0, 8.0, 6.0, 16, 12)

    def view(name: str, degrees: float) -> SimpleNamespace:
        return SimpleNamespace(name=name, camera=turned(degrees))

    scene = SimpleNamespace(
        train=[view("t0", 0.0), view("t1", 40.0)], test=[view("a", 25.0), view("b", -30.0)]
    )
    angles = per_view.nearest_training_angles(scene)
    assert angles == pytest.approx({"a": 15.0, "b": 30.0}, abs=1e-9)


def test_per_view_rows_average_each_view_over_seeds(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from benchmarks import per_view

    scene = SimpleNamespace(name="s", train=[], test=[])
    monkeypatch.setattr(per_view, "nearest_training_angles", lambda s: {"v1": 10.0, "v2": 20.0})
    for seed, (a, b) in enumerate([(10.0, 20.0), (12.0, 23.0)]):
        run = tmp_path / f"run{seed}"
        run.mkdir()
        views = {"v1": {"psnr": a}, "v2": {"psnr": b}}
        (run / "metrics.json").write_text(json.dumps({"psnr": (a + b) / 2, "views": views}))
    results = [
        {"scene": "s", "variant": "full", "seed": i, "out_dir": str(tmp_path / f"run{i}")}
        for i in (0, 1)
    ] + [{"scene": "s", "variant": "no_depth", "error": "boom", "out_dir": "nowhere"}]
    rows = per_view.per_view_rows(results, scene, ["full"])
    assert [(r["view"], r["angle_deg"], r["full"]) for r in rows] == [
        ("v1", 10.0, 11.0),
        ("v2", 20.0, 21.5),
    ]
    assert rows[0]["full_seeds"] == "0,1"
    with pytest.raises(SystemExit, match="no 'no_depth' run of s"):
        per_view.per_view_rows(results, scene, ["no_depth"])


def test_best_gain_finds_a_planted_per_channel_brightness_inside_the_mask() -> None:
    """The gain is the float64 least-squares fit over the mask's full pixels only: a photo that
    is the render dimmed by (0.7, 0.8, 0.9) inside the mask (anything outside) gives exactly
    that gain; with noise added the gained error is never above the error as rendered (the
    fit's optimum, and clipping to [0, 1] only moves values toward a photo in [0, 1]); a
    channel the render leaves black keeps a gain of 1."""
    import numpy as np

    from benchmarks.per_view import best_gain

    rng = np.random.default_rng(7)
    render = rng.uniform(0.0, 1.0, (12, 16, 3))
    mask = np.zeros((12, 16))
    mask[3:9, 4:12] = 1.0
    mask[0, 0] = 0.5  # partial: outside DTU's "exactly 1" mask
    planted = np.array([0.7, 0.8, 0.9])
    truth = rng.uniform(0.0, 1.0, (12, 16, 3))
    inside = mask == 1.0
    truth[inside] = render[inside] * planted
    assert best_gain(render, truth, mask) == pytest.approx(planted, abs=1e-12)
    assert not np.allclose(best_gain(render, truth, None), planted, atol=1e-3)

    noisy = np.clip(truth + rng.normal(0.0, 0.05, truth.shape), 0.0, 1.0)
    gain = best_gain(render, noisy, mask)
    gained = np.clip(render * gain, 0.0, 1.0)
    assert ((gained - noisy)[inside] ** 2).mean() <= ((render - noisy)[inside] ** 2).mean()

    dark = render.copy()
    dark[..., 2] = 0.0
    assert best_gain(dark, truth, mask)[2] == 1.0


def test_per_view_rows_add_a_gain_column_per_variant_when_asked(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """With ``gain`` each variant gets ``<variant>_gain``, scored with the gain applied (the
    flag reaches the scoring) and averaged over the seeds like the plain column."""
    from benchmarks import per_view

    scene = SimpleNamespace(name="s", train=[], test=[])
    monkeypatch.setattr(per_view, "nearest_training_angles", lambda s: {"v1": 10.0})
    table = {("a", False): 10.0, ("b", False): 12.0, ("a", True): 11.0, ("b", True): 14.0}

    def scored(out_dir: Path, _scene: object, gain: bool = False) -> dict[str, float]:
        return {"v1": table[(out_dir.name, gain)]}

    monkeypatch.setattr(per_view, "view_psnr_of_run", scored)
    results = [
        {"scene": "s", "variant": "full", "seed": i, "out_dir": f"runs/{name}"}
        for i, name in enumerate("ab")
    ]
    rows = per_view.per_view_rows(results, scene, ["full"], gain=True)
    assert (rows[0]["full"], rows[0]["full_gain"]) == (11.0, 12.5)
    assert "full_gain" not in per_view.per_view_rows(results, scene, ["full"])[0]
