"""``sparsesplat train`` through the real command: output formats, presets, logging, and a
clear message with exit code 2 for each mistake issue #11 found (no tracebacks)."""

from __future__ import annotations

import json
import re
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
import torch

from sparsesplat.engine.commands import train as train_cmd
from sparsesplat.engine.train import PRESETS
from sparsesplat.engine.train.config.presets import (
    DEFAULT_TIME_LIMIT_S,
    LAYOUT_RECIPES,
    PRESET_ITERATIONS,
)
from tests.cli.conftest import SMOKE, run_cli, strict_json
from tests.cli.scenes import shrink_images, write_object_scene

Meta = dict[str, Any]


def test_help_lists_presets_prior_kinds_and_exit_codes() -> None:
    result = run_cli("train", "--help")
    assert result.returncode == 0
    text = result.stdout
    for kind in ("pydnet", "plane_sweep", "onnx:FILE", "user", "none"):
        assert kind in text
    for name in PRESETS:
        assert f"  {name} " in text, name
        line = train_cmd._PRESET_HELP[name]
        lengths = [PRESET_ITERATIONS[name]]
        lengths += [
            r["iterations"] for r in LAYOUT_RECIPES.get(name, {}).values() if "iterations" in r
        ]
        assert [int(n) for n in re.findall(r"(\d+) iterations", line)] == sorted(lengths), name
    assert "images have alpha" in text and "plain white/black backdrop" in text
    assert "exit codes" in text
    assert f"default length trains for at most {DEFAULT_TIME_LIMIT_S:g} s" in text
    assert set(train_cmd.PRESET_NAMES) == set(PRESETS), "help must name exactly the presets"


def test_json_output_is_one_object_per_line_and_metrics_are_valid_json(
    trained: tuple[Path, Path, list[str]],
) -> None:
    _, out, lines = trained
    events = [strict_json(line) for line in lines]
    assert all(isinstance(e, dict) for e in events)
    kinds = [e["kind"] for e in events]  # type: ignore[index]
    assert kinds[0] == "preset" and kinds[-1] == "result" and "record" in kinds
    preset = events[0]
    assert preset["preset"] == "object" and "alpha" in preset["reason"]  # type: ignore[index]
    result = events[-1]
    assert isinstance(result, dict) and result["background_psnr"] is not None
    assert result["psnr"] > result["background_psnr"]
    metrics = strict_json((out / "metrics.json").read_text())
    assert isinstance(metrics, dict) and metrics["preset"] == "object"
    model = torch.load(out / "checkpoint.pt", weights_only=False)
    assert model["background"].tolist() == [1.0, 1.0, 1.0], "alpha images default to white"


def test_default_output_is_a_progress_line_and_log_level_works(tmp_path: Path) -> None:
    scene = write_object_scene(tmp_path / "s", size=24, alpha=False)
    env = {"SPARSESPLAT_LOG_LEVEL": "INFO"}
    result = run_cli("train", str(scene), "--out", str(tmp_path / "run"), *SMOKE, env=env)
    assert result.returncode == 0, result.stderr[-3000:]
    err = result.stderr
    assert "preset object: the images show an object on a plain black backdrop" in err
    assert "20/20 [####################]" in err and "left" in err and "PSNR" in err
    assert "(background " in err
    assert "loading native CPU extensions" in err, "SPARSESPLAT_LOG_LEVEL=INFO reaches the engine"
    assert "constant background" in result.stdout and "metrics.json" in result.stdout
    assert "Traceback" not in err


def test_an_empty_model_is_flagged(tmp_path: Path) -> None:
    scene = write_object_scene(tmp_path / "s", size=24)
    args = [*SMOKE, "--set", "init_opacity=0.005", "--set", "init_points=20"]
    args[1] = "2"  # --iterations 2: a nearly transparent model
    result = run_cli("train", str(scene), "--out", str(tmp_path / "run"), *args)
    assert result.returncode == 0, result.stderr[-3000:]
    # With the bounds framed by what every camera sees, 20 faint points may also leave the
    # renders empty: the one warning names both problems.
    warning = next(line for line in result.stderr.splitlines() if "warning:" in line)
    assert warning.startswith("sparsesplat train: warning: ") and "held-out PSNR" in warning
    assert "no better than a constant background image" in result.stderr
    assert result.stderr.count("no better than") == 1, "said once"
    metrics = json.loads((tmp_path / "run" / "metrics.json").read_text())
    assert metrics["warnings"] and metrics["coverage"] < 0.05
    assert metrics["psnr"] < metrics["background_psnr"] + 0.5


def _reflect(m: Meta) -> None:
    row = m["frames"][1]["matrix"][0]
    m["frames"][1]["matrix"][0] = [-row[0], -row[1], -row[2], row[3]]


def _tiny(which: str) -> Callable[[Path], None]:
    def shrink(root: Path) -> None:
        shrink_images(root, which)

    return shrink


def _face_away(m: Meta) -> None:
    import numpy as np

    for f in m["frames"]:
        c2w = np.array(f["matrix"])
        c2w[:3, :3] = c2w[:3, :3] @ np.diag([-1.0, 1.0, -1.0])
        f["matrix"] = c2w.tolist()


# (id, cameras.json edit, folder edit, extra args, needles in stderr)
BAD: list[tuple[str, Any, Any, list[str], list[str]]] = [
    ("typo convention", lambda m: m.update(convension=m.pop("convention")), None, [],
     ["unknown field 'convension' — did you mean 'convention'?"]),
    ("typo split", lambda m: m["frames"][0].update(spilt=m["frames"][0].pop("split")), None, [],
     ["did you mean 'split'?"]),
    ("missing convention", lambda m: m.pop("convention"), None, [],
     ["missing 'convention': say 'opencv'", "'opengl' (+x right, +y up, +z back"]),
    ("transform_matrix", lambda m: m["frames"][0].update(
        transform_matrix=m["frames"][0].pop("matrix")), None, [],
     ["unknown field 'transform_matrix' — did you mean 'matrix'?"]),
    ("duplicate image", lambda m: m["frames"][1].update(image=m["frames"][0]["image"]), None, [],
     ["listed more than once"]),
    ("reflection", _reflect, None, [], ["determinant -1"]),
    ("translation 1e30", lambda m: m["frames"][1]["matrix"][0].__setitem__(3, 1e30), None, [],
     ["frame 'r_1.png'", "too large"]),
    ("cameras face away", _face_away, None, [], ["no two cameras see a common region"]),
    ("1x1 held-out images", None, _tiny("test"), [], ["1x1 pixels; at least 16x16"]),
    ("all images 1x1", None, _tiny("all"), [], ["1x1 pixels; at least 16x16"]),
    ("background name typo", None, None, ["--set", "background=whte"],
     ["background must be white, black, gray, mean or 3 numbers"]),
    ("field typo", None, None, ["--set", "lamda_dssim=0.2"],
     ["did you mean photometric.lambda_dssim?"]),
    ("dotted field typo", None, None, ["--set", "depth.soft_strat=5"],
     ["depth.soft_strat (did you mean depth.soft_start?)"]),
    ("field type", None, None, ["--set", "init_points=many"], ["init.points must be int"]),
    ("iterations twice", None, None, ["--set", "iterations=30"],
     ["give either --iterations or --set iterations=N"]),
    ("too many views", None, None, ["--views", "9"], ["views=9 training views requested"]),
    ("budget 0", None, None, ["--time-budget", "0"], ["--time-budget must be > 0 seconds"]),
    ("budget nan", None, None, ["--time-budget", "nan"], ["--time-budget must be > 0 seconds"]),
    ("budget and iterations", None, None, ["--time-budget", "5"],
     ["give either --iterations or --time-budget"]),
]  # fmt: skip


@pytest.mark.parametrize(("edit", "prepare", "extra", "needles"), [b[1:] for b in BAD],
                         ids=[b[0] for b in BAD])  # fmt: skip
def test_bad_input_is_a_message_and_exit_2(
    tmp_path: Path, edit: Any, prepare: Any, extra: list[str], needles: list[str]
) -> None:
    scene = write_object_scene(tmp_path / "s", size=24, edit=edit)
    if prepare is not None:
        prepare(scene)
    result = run_cli("train", str(scene), "--out", str(tmp_path / "run"), *SMOKE, *extra)
    assert result.returncode == 2, (result.returncode, result.stderr[-3000:])
    assert "Traceback" not in result.stderr
    assert result.stderr.startswith("sparsesplat train: "), result.stderr
    for needle in needles:
        assert needle in result.stderr, result.stderr


def test_missing_scene_folder_and_cuda_on_a_cpu_torch(tmp_path: Path) -> None:
    result = run_cli("train", str(tmp_path / "nope"), "--out", str(tmp_path / "run"))
    assert result.returncode == 2 and "scene folder not found" in result.stderr
    if torch.cuda.is_available():
        pytest.skip("CUDA is available here: --device cuda is valid")
    scene = write_object_scene(tmp_path / "s", size=24)
    result = run_cli("train", str(scene), "--out", str(tmp_path / "run"), "--device", "cuda")
    assert result.returncode == 2, result.stderr[-3000:]
    assert "--device cuda" in result.stderr and "use --device cpu" in result.stderr
    assert "Traceback" not in result.stderr


def test_time_budget_trains_until_it_is_spent(tmp_path: Path) -> None:
    scene = write_object_scene(tmp_path / "s", size=24)
    i = SMOKE.index("--iterations")
    args = [*SMOKE[:i], *SMOKE[i + 2 :], "--time-budget", "2", "--json"]
    result = run_cli("train", str(scene), "--out", str(tmp_path / "run"), *args)
    assert result.returncode == 0, result.stderr[-3000:]
    events = [strict_json(line) for line in result.stdout.splitlines()]
    budget = next(e for e in events if e["kind"] == "budget")
    final = next(e for e in events if e["kind"] == "result")
    assert budget["seconds"] == 2.0 and budget["schedule_iterations"] >= 1
    # a deadline: at least the budget, and not much more (one smoke iteration is ~0.1 s)
    assert final["time_budget_s"] == 2.0 and 2.0 <= final["seconds"] < 3.0, final
    assert final["iterations"] >= 1
