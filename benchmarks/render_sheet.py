"""``make bench-render-sheet``: held-out renders beside the truth, as small JPEGs under docs/.

For each ``SCENE=RUN`` pair (a scene folder and a trained run: its folder or checkpoint), the
held-out views of the scene's paper split are rendered by the trained model and laid out one row
per view: truth | render | absolute error (x4), each row labelled with that view's held-out
scores as the run's own evaluation computes them (the one ``Evaluator``: PSNR inside the object
mask where the scene has masks, as DTU's protocol scores, with the whole image's PSNR beside it;
LPIPS when its weights are found). The sheet is what a user sees, so anyone can judge the
quality without trusting the numbers alone. Example:

    make bench-quality BENCH_ARGS="../shared/data/nerf_llff_data --scenes flower --runs-dir runs"
    make bench-render-sheet BENCH_ARGS="flower=runs/flower/full_seed0 --data ../shared/data"
"""

from __future__ import annotations

import argparse
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from PIL import Image, ImageDraw

if TYPE_CHECKING:
    from sparsesplat.engine.metrics.evaluate import Evaluator
    from sparsesplat.engine.model import TrainedModel
    from sparsesplat.engine.scene import Scene

TILE_HEIGHT = 189
"""Each tile is scaled to this height (a 504x378 view at half size)."""
MAX_VIEWS = 3
"""Held-out views per sheet, evenly spaced over the held-out list."""
DOCS_DIR = Path(__file__).resolve().parents[1] / "docs" / "render-sheets"
"""Where the sheets go by default."""


def _tile(array: np.ndarray) -> Image.Image:
    """(H, W, 3) floats in [0, 1] -> a TILE_HEIGHT-high RGB image."""
    img = Image.fromarray((np.clip(array, 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8))
    width = max(1, round(img.width * TILE_HEIGHT / img.height))
    return img.resize((width, TILE_HEIGHT), Image.Resampling.BILINEAR)


@dataclass
class SheetRow:
    """One held-out view of a sheet: the images and the scores its label shows."""

    name: str
    """The view's name."""
    truth: np.ndarray
    """(H, W, 3) held-out photo in [0, 1]."""
    render: np.ndarray
    """(H, W, 3) the model's render of the view, clamped to [0, 1]."""
    psnr: float
    """PSNR as the run's evaluation scores it (inside the object mask when ``masked``)."""
    lpips: float | None
    """LPIPS as the run's evaluation scores it; None without the network's weights."""
    masked: bool
    """Whether the view has an object mask (then ``psnr`` is DTU's masked PSNR)."""
    whole_psnr: float
    """PSNR over the whole image (equal to ``psnr`` without a mask)."""

    def label(self) -> str:
        """The row's caption, e.g. ``000001: 11.17 dB in the object mask (whole image 9.30
        dB), LPIPS 0.383``."""
        text = f"{self.name}: {self.psnr:.2f} dB"
        if self.masked:
            text += f" in the object mask (whole image {self.whole_psnr:.2f} dB)"
        if self.lpips is not None:
            text += f", LPIPS {self.lpips:.3f}"
        return text


def sheet_rows(scene: Scene, model: TrainedModel, evaluator: Evaluator) -> list[SheetRow]:
    """Render up to :data:`MAX_VIEWS` evenly spaced held-out views of ``scene`` with ``model``
    and score each with ``evaluator`` the way a run's held-out records do (the same numbers
    as the run's ``metrics.json`` ``views``)."""
    import torch

    from sparsesplat.engine.metrics.image import psnr, quantize

    step = max(1, len(scene.test) // MAX_VIEWS)
    rows: list[SheetRow] = []
    for view in scene.test[::step][:MAX_VIEWS]:
        with torch.no_grad():
            image = model.render(view.camera).image.permute(1, 2, 0).clamp(0, 1)
        truth = view.image[..., :3]
        scores = evaluator.score_view(image, truth, view.mask, key=view.name)
        score = scores["psnr"]
        assert score is not None  # PSNR is scored on every view
        rows.append(
            SheetRow(
                name=view.name,
                truth=truth.numpy(),
                render=image.numpy(),
                psnr=score,
                lpips=scores["lpips"],
                masked=view.mask is not None,
                # The evaluation's 8-bit rounding, so an unmasked view's two PSNRs agree.
                whole_psnr=psnr(quantize(image), quantize(truth)),
            )
        )
    return rows


def render_sheet(scene_dir: Path, run: Path, out: Path, title: str = "") -> Path:
    """Render the held-out views of ``scene_dir`` with the model of ``run``; write ``out``."""
    from sparsesplat.engine.datasets import load_scene
    from sparsesplat.engine.metrics.evaluate import PSNR_CEILING, Evaluator
    from sparsesplat.engine.model import load_model

    scene = load_scene(scene_dir)
    model = load_model(run)
    if not scene.test:
        raise SystemExit(f"{scene_dir}: the scene has no held-out views")
    evaluator = Evaluator(lpips_mode="optional", psnr_ceiling=PSNR_CEILING)
    sheet_views = sheet_rows(scene, model, evaluator)
    rows: list[Image.Image] = []
    for view in sheet_views:
        error = np.abs(view.render - view.truth) * 4.0
        tiles = [_tile(view.truth), _tile(view.render), _tile(error)]
        row = Image.new("RGB", (sum(t.width for t in tiles) + 8, TILE_HEIGHT), (255, 255, 255))
        x = 0
        for tile in tiles:
            row.paste(tile, (x, 0))
            x += tile.width + 4
        rows.append(row)
    labels = [view.label() for view in sheet_views]
    header, label_h = 22, 14
    heading = title or f"{scene.name}: truth | render | |error| x4  ({len(model)} Gaussians)"
    width = max(r.width for r in rows)
    sheet = Image.new(
        "RGB", (width, header + sum(r.height + label_h + 4 for r in rows)), (255, 255, 255)
    )
    draw = ImageDraw.Draw(sheet)
    draw.text((4, 4), heading, fill=(0, 0, 0))
    y = header
    for row, label in zip(rows, labels, strict=True):
        draw.text((4, y), label, fill=(0, 0, 0))
        sheet.paste(row, (0, y + label_h))
        y += row.height + label_h + 4
    out.parent.mkdir(parents=True, exist_ok=True)
    sheet.save(out, quality=80)
    return out


def main() -> None:
    """Write one sheet per ``NAME=RUN`` argument."""
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("pairs", nargs="+", help="SCENE=RUN: a scene name (or folder) and a run")
    parser.add_argument("--data", type=Path, default=None, help="folder searched for scene names")
    parser.add_argument("--out-dir", type=Path, default=DOCS_DIR, help="where the JPEGs go")
    args = parser.parse_args()
    for pair in args.pairs:
        name, sep, run = pair.partition("=")
        if not sep:
            raise SystemExit(f"{pair!r}: expected SCENE=RUN")
        scene_dir = Path(name)
        if not scene_dir.is_dir() and args.data is not None:
            found = sorted(p for p in args.data.glob(f"*/{name}") if p.is_dir())
            scene_dir = found[0] if found else scene_dir
        if not scene_dir.is_dir():
            raise SystemExit(f"{name}: no such scene folder (give a path or --data)")
        out = render_sheet(scene_dir, Path(run), args.out_dir / f"{scene_dir.name}.jpg")
        print(f"wrote {out}")


if __name__ == "__main__":
    main()
