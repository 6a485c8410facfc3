"""Contact sheet: each training view beside its depth prior and confidence."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np
from PIL import Image, ImageDraw

from sparsesplat.engine.images import to_uint8
from sparsesplat.engine.priors.base import PriorDepth
from sparsesplat.engine.scene import Scene

TILE_HEIGHT = 240
"""Rows are scaled to this height in pixels."""


def colorize_depth(depth: np.ndarray, confidence: np.ndarray) -> np.ndarray:
    """Depth -> RGB with a perceptual colormap (near = red, far = blue), normalised by the
    2nd/98th percentiles of the confident pixels; unconfident pixels are washed out grey.
    Positive (metric) depths are shown as inverse depth, which spreads near and far evenly
    over wide ranges (LLFF bounds span 1-120 units)."""
    from matplotlib import colormaps

    valid = confidence > 0.5
    sample = depth[valid] if valid.sum() > 20 else depth.reshape(-1)
    if sample.size and float(sample.min()) > 0:
        value, sample = -1.0 / np.maximum(depth, 1e-12), -1.0 / sample
    else:
        value = depth
    lo, hi = np.percentile(sample, [2, 98]) if sample.size else (0.0, 1.0)
    t = np.clip((value - lo) / max(hi - lo, 1e-12), 0, 1)
    rgb = colormaps["turbo"](1.0 - t)[..., :3]
    grey = np.full_like(rgb, 0.35)
    return np.where(valid[..., None], rgb, 0.5 * rgb + 0.5 * grey)


def _tile(array: np.ndarray) -> Image.Image:
    img = Image.fromarray(to_uint8(array))
    w = max(1, round(img.width * TILE_HEIGHT / img.height))
    img = img.resize((w, TILE_HEIGHT), Image.Resampling.BILINEAR)
    ImageDraw.Draw(img).rectangle((0, 0, w - 1, TILE_HEIGHT - 1), outline=(128, 128, 128))
    return img


def contact_sheet(
    scene: Scene, priors: Sequence[PriorDepth], path: str | Path, title: str = ""
) -> Path:
    """Write a PNG with one row per training view: image | depth prior | confidence."""
    rows = []
    for i, view in enumerate(scene.train):
        tiles = [_tile(view.image.numpy())]
        if i < len(priors):
            depth = priors[i].depth.numpy()
            conf = priors[i].confidence.numpy()
            tiles.append(_tile(colorize_depth(depth, conf)))
            tiles.append(_tile(np.repeat(conf[..., None], 3, axis=2)))
        width = sum(t.width for t in tiles) + 4 * (len(tiles) - 1)
        row = Image.new("RGB", (width, TILE_HEIGHT), (255, 255, 255))
        x = 0
        for tile in tiles:
            row.paste(tile, (x, 0))
            x += tile.width + 4
        rows.append(row)
    header = 24
    kind = priors[0].kind if priors else "none"
    text = title or (
        f"{scene.name} ({scene.format}) - prior: {kind} - image | depth (red near, blue far; "
        "grey = not confident) | confidence (white = 1)"
    )
    width = max(max(r.width for r in rows), 6 * len(text) + 12)  # room for the title
    sheet = Image.new("RGB", (width, header + sum(r.height + 4 for r in rows)), (255, 255, 255))
    ImageDraw.Draw(sheet).text((6, 6), text, fill=(0, 0, 0))
    y = header
    for row in rows:
        sheet.paste(row, (0, y))
        y += row.height + 4
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    sheet.save(path)
    return path
