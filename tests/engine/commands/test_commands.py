"""The train/render CLI modules: no torch at import, render writes the PNG a model produces."""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import torch
from PIL import Image

from sparsesplat.engine.commands import render as render_cmd
from sparsesplat.engine.commands import train as train_cmd
from sparsesplat.engine.model import load_model
from sparsesplat.engine.synthetic import make_scene
from sparsesplat.engine.train import Trainer
from tests.engine.train.loop.test_trainer import small


def test_modules_do_not_import_torch() -> None:
    for mod in ("train", "render"):
        code = f"import sys, sparsesplat.engine.commands.{mod}; print('torch' in sys.modules)"
        out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
        assert out.stdout.strip() == "False", (mod, out.stderr)


def _parse(module, argv: list[str]) -> argparse.Namespace:  # type: ignore[no-untyped-def]
    parser = argparse.ArgumentParser()
    module.add_arguments(parser)
    return parser.parse_args(argv)


def test_render_command_writes_png(tmp_path: Path) -> None:
    scene, priors = make_scene(seed=8)
    Trainer(scene, small(iterations=10), priors, tmp_path / "run").run()
    cam = scene.test[0].camera
    spec = {
        "convention": "opencv", "pose": "world_to_camera",
        "matrix": cam.world_to_camera.tolist(),
        "fx": cam.fx, "fy": cam.fy, "cx": cam.cx, "cy": cam.cy,
        "width": cam.width, "height": cam.height,
    }  # fmt: skip
    (tmp_path / "cam.json").write_text(json.dumps(spec))
    out = tmp_path / "view.png"
    args = _parse(render_cmd, [str(tmp_path / "run"), "--camera", str(tmp_path / "cam.json"),
                               "-o", str(out)])  # fmt: skip
    assert render_cmd.run(args) == 0
    png = np.asarray(Image.open(out)).astype(np.float32) / 255.0
    want = load_model(tmp_path / "run").render(cam).image.clamp(0, 1).permute(1, 2, 0).numpy()
    assert png.shape == (24, 32, 3) and np.abs(png - want).max() <= 1 / 255 + 1e-6
    bad = _parse(render_cmd, [str(tmp_path / "run"), "--camera", "{}", "-o", str(out)])
    assert render_cmd.run(bad) == 2


def test_train_command_options() -> None:
    args = _parse(train_cmd, ["scene", "--out", "o", "--no-depth", "--iterations", "7",
                              "--set", "lambda_dssim=0.3"])  # fmt: skip
    spec = train_cmd.run_spec(args)
    assert spec.overrides == {"lambda_dssim": 0.3, "depth.prior": "none"}
    assert (spec.iterations, spec.time_budget_s, spec.preset) == (7, None, None)
    assert torch.is_tensor(torch.zeros(1))


def test_progress_line_under_a_budget_counts_training_seconds() -> None:
    """A deadline has no iteration total: the bar and the time left follow the budget."""
    import io

    stream = io.StringIO()
    line = train_cmd.ProgressLine(1500, 12.0, stream, budget_s=60.0)
    line.record(40, 20.5, trained_s=30.0)
    text = stream.getvalue()
    assert text.startswith("40 it [" + "#" * 10 + "-" * 10 + "]"), text
    assert "left 00:30" in text and "PSNR 20.50 dB (background 12.00)" in text


def test_progress_line_under_a_limit_follows_whichever_ends_first() -> None:
    """A default-length run ends after its iterations or at its time limit, whichever first."""
    import io

    stream = io.StringIO()
    line = train_cmd.ProgressLine(3000, None, stream, limit_s=590.0)
    line.start -= 100.0  # 100 s of wall time behind the first record
    line.record(300, 18.0, trained_s=295.0)  # a tenth of the iterations, half the limit
    text = stream.getvalue()
    assert text.startswith("300/3000 [" + "#" * 10 + "-" * 10 + "]"), text
    assert "left 04:55" in text, text  # the limit's 295 s, not the iterations' ~900 s


def test_progress_line_says_which_held_out_views_a_psnr_scored() -> None:
    """Interim records on 4 of 5 views say so; the final record after them says all 5 (the
    two share the last iteration and differ in PSNR). A scene whose records all score every
    view shows no label."""
    import io

    stream = io.StringIO()
    line = train_cmd.ProgressLine(3000, None, stream)
    line.record(3000, 18.88, trained_s=420.0, views=(4, 5))
    line.record(3000, 20.13, trained_s=420.0, views=(5, 5), final=True)
    closing, final = stream.getvalue().splitlines()
    assert closing.endswith("PSNR 18.88 dB on 4 of 5 views"), closing
    assert final.endswith("PSNR 20.13 dB on all 5 views"), final

    stream = io.StringIO()
    line = train_cmd.ProgressLine(3000, None, stream)
    line.record(1000, 17.5, trained_s=100.0, views=(3, 3))
    line.record(3000, 19.0, trained_s=300.0, views=(3, 3), final=True)
    assert all(row.endswith(" dB") for row in stream.getvalue().splitlines())
