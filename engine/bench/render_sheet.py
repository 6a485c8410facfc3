"""``make bench-render-sheet``: held-out renders beside the truth, as small JPEGs under docs/.

For each ``SCENE=RUN`` pair (a scene folder and a trained run: its folder or checkpoint), the
held-out views of the scene's paper split are rendered by the trained model and laid out one row
per view: truth | render | absolute error (x4), each row labelled with its PSNR. The sheet is
what a user sees, so anyone can judge the quality without trusting the numbers alone. Example:

    make bench-quality BENCH_ARGS="../shared/data/nerf_llff_data --scenes flower --runs-dir runs"
    make bench-render-sheet BENCH_ARGS="flower=runs/flower/full_seed0 --data ../shared/data"
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
from PIL import Image, ImageDraw

TILE_HEIGHT = 189
"""Each tile is scaled to this height (a 504x378 view at half size)."""
MAX_VIEWS = 3
"""Held-out views per sheet, evenly spaced over the held-out list."""
DOCS_DIR = Path(__file__).resolve().parents[2] / "docs" / "render-sheets"
"""Where the sheets go by default."""


def _tile(array: np.ndarray) -> Image.Image:
    """(H, W, 3) floats in [0, 1] -> a TILE_HEIGHT-high RGB image."""
    img = Image.fromarray((np.clip(array, 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8))
    width = max(1, round(img.width * TILE_HEIGHT / img.height))
    return img.resize((width, TILE_HEIGHT), Image.Resampling.BILINEAR)


def render_sheet(scene_dir: Path, run: Path, out: Path, title: str = "") -> Path:
    """Render the held-out views of ``scene_dir`` with the model of ``run``; write ``out``."""
    import torch

    from sparsesplat.engine.datasets import load_scene
    from sparsesplat.engine.metrics.image import psnr
    from sparsesplat.engine.train import load_model

    scene = load_scene(scene_dir)
    model = load_model(run)
    if not scene.test:
        raise SystemExit(f"{scene_dir}: the scene has no held-out views")
    step = max(1, len(scene.test) // MAX_VIEWS)
    rows: list[Image.Image] = []
    labels: list[str] = []
    for view in scene.test[::step][:MAX_VIEWS]:
        with torch.no_grad():
            image = model.render(view.camera).image.clamp(0, 1).permute(1, 2, 0).numpy()
        truth = view.image[..., :3].numpy()
        error = np.abs(image - truth) * 4.0
        tiles = [_tile(truth), _tile(image), _tile(error)]
        row = Image.new("RGB", (sum(t.width for t in tiles) + 8, TILE_HEIGHT), (255, 255, 255))
        x = 0
        for tile in tiles:
            row.paste(tile, (x, 0))
            x += tile.width + 4
        rows.append(row)
        labels.append(f"{view.name}: {psnr(image, truth):.2f} dB")
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
