"""``make bench-render-sheet``: one row per held-out view, labelled with that view's PSNR."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from PIL import Image

from benchmarks.render_sheet import MAX_VIEWS, TILE_HEIGHT, render_sheet
from sparsesplat.engine.datasets import load_scene
from sparsesplat.engine.train import Trainer, preset
from tests.cli.scenes import write_object_scene


def test_sheet_has_a_row_per_held_out_view_with_truth_render_and_error(tmp_path: Path) -> None:
    """A trained smoke model's sheet: the truth tile is the held-out photo (scaled), the
    render tile differs from it, and the sheet's height is one header plus one row per view."""
    scene_dir = write_object_scene(tmp_path / "scene", count=6, test=2, size=32, alpha=False)
    scene = load_scene(scene_dir)
    config = preset(
        "object", iterations=5, **{"record.export": False, "record.eval_lpips": False},
        **{"depth.prior": "none", "record.eval_interval_s": 0},
    )  # fmt: skip
    Trainer(scene, config, None, tmp_path / "run").run()
    out = render_sheet(scene_dir, tmp_path / "run", tmp_path / "sheet.jpg")
    sheet = np.asarray(Image.open(out).convert("RGB"), dtype=np.float64)
    rows = min(len(scene.test), MAX_VIEWS)
    header, label = 22, 14
    assert sheet.shape[0] == header + rows * (TILE_HEIGHT + label + 4)
    # The first row's truth tile is the first held-out photo, scaled to the tile height.
    y0 = header + label
    truth = Image.fromarray((scene.test[0].image.numpy() * 255 + 0.5).astype(np.uint8))
    want = np.asarray(truth.resize((TILE_HEIGHT, TILE_HEIGHT), Image.Resampling.BILINEAR))
    tile = sheet[y0 : y0 + TILE_HEIGHT, :TILE_HEIGHT]
    assert np.abs(tile - want).mean() < 4.0  # JPEG at quality 80
    render = sheet[y0 : y0 + TILE_HEIGHT, TILE_HEIGHT + 4 : 2 * TILE_HEIGHT + 4]
    assert np.abs(render - want).mean() > 4.0  # five iterations do not reproduce the photo


def test_rows_score_each_view_as_the_runs_own_evaluation(tmp_path: Path) -> None:
    """The labels are the run's held-out numbers: on views with an object mask the sheet's
    PSNR is the masked PSNR the run's metrics.json reports per view (not the whole image's,
    which it shows beside it), and without a mask the two PSNRs are one number."""
    import json
    from dataclasses import replace

    import torch

    from benchmarks.render_sheet import sheet_rows
    from sparsesplat.engine.metrics.evaluate import PSNR_CEILING, Evaluator
    from sparsesplat.engine.model import load_model

    scene_dir = write_object_scene(tmp_path / "scene", count=6, test=2, size=32, alpha=False)
    plain = load_scene(scene_dir)
    mask = torch.zeros(32, 32, dtype=torch.bool)
    mask[6:26, 4:24] = True  # an off-centre object region
    masked = replace(plain, test=[replace(v, mask=mask) for v in plain.test])
    config = preset(
        "object", iterations=5, **{"record.export": False, "record.eval_lpips": False},
        **{"depth.prior": "none", "record.eval_interval_s": 0},
    )  # fmt: skip
    Trainer(masked, config, None, tmp_path / "run").run()
    reported = json.loads((tmp_path / "run" / "metrics.json").read_text())["views"]
    model = load_model(tmp_path / "run")
    evaluator = Evaluator(lpips_mode="off", psnr_ceiling=PSNR_CEILING)

    rows = sheet_rows(masked, model, evaluator)
    assert [r.name for r in rows] == [v.name for v in masked.test][: len(rows)]
    for row in rows:
        assert row.masked and "in the object mask" in row.label()
        assert abs(row.psnr - reported[row.name]["psnr"]) < 1e-9
        # Five iterations leave the corners wrong too: the whole image scores differently.
        assert abs(row.whole_psnr - row.psnr) > 0.01
    for row in sheet_rows(plain, model, evaluator):
        assert not row.masked and row.whole_psnr == row.psnr
        assert row.label() == f"{row.name}: {row.psnr:.2f} dB"
