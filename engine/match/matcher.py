"""Keypoints and matches for N photos with one of the learned matchers, on the CPU.

``match_images(photos, settings, masks)`` matches every pair of photos and returns a
:class:`MatchSet`. Keypoints off the usable pixels (outside a caller's mask, e.g. an image's
alpha or an object mask; on a flat patch such as a white or black backdrop) are dropped before
matching, so background matches never reach the caller.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch
from torch import Tensor

from sparsesplat.engine.match import networks
from sparsesplat.engine.match.errors import MatchError
from sparsesplat.engine.match.images import Prepared, as_float_rgb, prepare, to_photo, usable_at
from sparsesplat.engine.match.result import MatchSet
from sparsesplat.engine.match.settings import MatchSettings

STRIDE = {"xfeat": 32, "disk": 16}
"""Side multiple each backbone needs (padding, never a resize, so pixel positions stay exact)."""
SEMI_DENSE_BIAS = (4.0, 2.9)
"""XFeat's semi-dense positions are pixel indices at the scale a feature was extracted at (0.6
or 1.3 of the photo): (refined, coarse) offsets, in pixels of that scale, from the reported
position to the point the feature stands for (the half pixel of pixel-index coordinates
included). Measured by matching photos against 1.5x enlarged copies of themselves, both ways
round, and fitting the two offsets by least squares over the matches of both scales (crops of
flower, horns and DTU scan24, about 5000 matches: 3.98 and 2.90, residual 1.1 px rms)
(docs/experiments/2026-11-28-matchers.md)."""
FINE_CONFIDENCE = 0.25
"""XFeat's threshold on the refinement's peak probability (its own default)."""


@dataclass
class _Features:
    """Sparse keypoints of one photo: where (network and photo pixels) and their descriptors."""

    net_xy: Tensor
    """(K, 2) positions in the resized photo's pixel indices (what LightGlue is given)."""
    photo_xy: np.ndarray
    """(K, 2) float32 positions in the photo's own pixels, centres at +0.5."""
    descriptors: Tensor
    """(K, D) float32 unit descriptors."""


def _sparse(prep: Prepared, settings: MatchSettings) -> _Features:
    """Detect and describe one photo with XFeat or DISK; keep the usable keypoints."""
    w, h = prep.resized
    with torch.inference_mode():
        if settings.method.startswith("xfeat"):
            out = networks.xfeat().detectAndCompute(prep.tensor, top_k=settings.keypoints)[0]
            xy, desc = out["keypoints"].float(), out["descriptors"].float()
        else:
            feats = networks.disk()(
                prep.tensor, n=settings.keypoints, window_size=5, score_threshold=0.0
            )[0]
            xy, desc = feats.keypoints.float(), feats.descriptors.float()
    inside = (xy[:, 0] < w) & (xy[:, 1] < h)  # not in the padding
    xy, desc = xy[inside], desc[inside]
    photo = to_photo(xy, prep)
    keep = torch.from_numpy(usable_at(photo, prep))
    return _Features(xy[keep].contiguous(), photo[keep.numpy()], desc[keep].contiguous())


def _glue(
    net: torch.nn.Module, a: _Features, b: _Features, pa: Prepared, pb: Prepared, threshold: float
) -> tuple[np.ndarray, np.ndarray]:
    """LightGlue's matches (M, 2) and scores (M,) between two photos' features."""
    if len(a.net_xy) == 0 or len(b.net_xy) == 0:
        return np.zeros((0, 2), np.int32), np.zeros(0, np.float32)
    net.conf.filter_threshold = threshold  # type: ignore[union-attr]

    def side(f: _Features, p: Prepared) -> dict[str, Tensor]:
        size = torch.tensor([p.resized], dtype=torch.float32)
        return {"keypoints": f.net_xy[None], "descriptors": f.descriptors[None], "image_size": size}

    with torch.inference_mode():
        out = net({"image0": side(a, pa), "image1": side(b, pb)})
    rows = out["matches"][0].cpu().numpy().astype(np.int32).reshape(-1, 2)
    return rows, out["scores"][0].cpu().numpy().astype(np.float32)


def _mutual_nn(a: _Features, b: _Features, min_cosine: float) -> tuple[np.ndarray, np.ndarray]:
    """Mutual nearest neighbours of the descriptors with cosine above ``min_cosine``."""
    if len(a.descriptors) == 0 or len(b.descriptors) == 0:
        return np.zeros((0, 2), np.int32), np.zeros(0, np.float32)
    with torch.inference_mode():
        cos = a.descriptors @ b.descriptors.T
        best_ab, ab = cos.max(dim=1)
        ba = cos.argmax(dim=0)
        idx = torch.arange(len(ab))
        keep = (ba[ab] == idx) & (best_ab > min_cosine)
    rows = torch.stack([idx[keep], ab[keep]], dim=1).numpy().astype(np.int32)
    return rows, best_ab[keep].numpy().astype(np.float32)


def _semidense(
    preps: list[Prepared], settings: MatchSettings, pairs: list[tuple[int, int]]
) -> tuple[list[np.ndarray], dict[tuple[int, int], np.ndarray], float, float]:
    """XFeat's semi-dense matching: coarse features per photo (two scales), mutual nearest
    neighbours per pair, refined to sub-pixel in the pair's first photo. Returns keypoints per
    photo, match rows per pair and the extract / match seconds."""
    model = networks.xfeat()
    t0 = time.perf_counter()
    with torch.inference_mode():
        dense = [model.detectAndComputeDense(p.tensor, top_k=settings.keypoints) for p in preps]
    t1 = time.perf_counter()
    points: list[list[np.ndarray]] = [[] for _ in preps]
    counts = [0] * len(preps)
    rows: dict[tuple[int, int], np.ndarray] = {}
    with torch.inference_mode():
        for i, j in pairs:
            net_i, net_j = _refined_pair(model, dense[i], dense[j])
            xi, xj = to_photo(net_i, preps[i], 0.0), to_photo(net_j, preps[j], 0.0)
            keep = usable_at(xi, preps[i]) & usable_at(xj, preps[j])
            xi, xj = xi[keep], xj[keep]
            n = len(xi)
            rows[(i, j)] = np.stack(
                [np.arange(counts[i], counts[i] + n), np.arange(counts[j], counts[j] + n)], axis=1
            ).astype(np.int32)
            points[i].append(xi)
            points[j].append(xj)
            counts[i] += n
            counts[j] += n
    keypoints = [np.concatenate(p) if p else np.zeros((0, 2), np.float32) for p in points]
    keypoints, rows = _merge_duplicates(keypoints, rows)
    return keypoints, rows, t1 - t0, time.perf_counter() - t1


def _refined_pair(model: Any, a: dict[str, Tensor], b: dict[str, Tensor]) -> tuple[Tensor, Tensor]:
    """XFeat's semi-dense match of two photos' coarse features: mutual nearest neighbours,
    then the sub-pixel offset of the match in ``a`` from XFeat's fine matcher; matches whose
    refinement is unsure are dropped. Positions in the padded, resized photos (pixels), each
    moved by :data:`SEMI_DENSE_BIAS` at its own extraction scale."""
    idx0, idx1 = model.batch_match(a["descriptors"], b["descriptors"])[0]
    fa, fb = a["descriptors"][0][idx0], b["descriptors"][0][idx1]
    logits = model.net.fine_matcher(torch.cat([fa, fb], dim=-1))
    confident = torch.softmax(logits * 3, dim=-1).max(dim=-1).values > FINE_CONFIDENCE
    offsets = model.subpix_softmax2d(logits.view(-1, 8, 8))
    inv_a = a["scales"][0][idx0][:, None]  # 1 / extraction scale
    inv_b = b["scales"][0][idx1][:, None]
    xa = a["keypoints"][0][idx0] + (offsets + SEMI_DENSE_BIAS[0]) * inv_a
    xb = b["keypoints"][0][idx1] + SEMI_DENSE_BIAS[1] * inv_b
    return xa[confident], xb[confident]


def _merge_duplicates(
    keypoints: list[np.ndarray], rows: dict[tuple[int, int], np.ndarray]
) -> tuple[list[np.ndarray], dict[tuple[int, int], np.ndarray]]:
    """One keypoint per distinct position in each photo (the coarse side of a semi-dense match
    sits on a grid shared by all the photo's pairs: merged, it links tracks across pairs)."""
    merged, remap = [], []
    for kp in keypoints:
        unique, inverse = np.unique(kp, axis=0, return_inverse=True)
        merged.append(unique.astype(np.float32).reshape(-1, 2))
        remap.append(inverse.reshape(-1).astype(np.int32))
    out = {
        (i, j): np.stack([remap[i][r[:, 0]], remap[j][r[:, 1]]], axis=1)
        for (i, j), r in rows.items()
    }
    return merged, out


def match_images(
    photos: Sequence[np.ndarray | Tensor],
    settings: MatchSettings | None = None,
    masks: Sequence[np.ndarray | None] | None = None,
) -> MatchSet:
    """Match every pair of ``photos`` ((H, W, 3) uint8 or float RGB in [0, 1]).

    ``masks``: per photo an (H, W) bool map of where keypoints may lie (an object mask, an
    alpha channel above one half), or None for the whole photo. Flat patches are dropped in
    any case (``settings.min_texture``). Raises MatchError for fewer than two photos or
    unreadable input, MissingMatchDependency without the ``match`` extra."""
    settings = settings or MatchSettings()
    if len(photos) < 2:
        raise MatchError(f"matching needs at least two photos, got {len(photos)}")
    if masks is not None and len(masks) != len(photos):
        raise MatchError(f"{len(masks)} masks for {len(photos)} photos")
    start = time.perf_counter()
    stride = STRIDE["disk" if settings.method.startswith("disk") else "xfeat"]
    preps = [
        prepare(
            as_float_rgb(p, i),
            None if masks is None else masks[i],
            (settings.min_side, settings.max_side),
            stride,
            settings.min_texture,
            i,
        )
        for i, p in enumerate(photos)
    ]
    n = len(preps)
    pairs = [(i, j) for i in range(n) for j in range(i + 1, n)]
    scores: dict[tuple[int, int], np.ndarray] = {}
    if settings.method == "xfeat-semidense":
        keypoints, rows, t_extract, t_match = _semidense(preps, settings, pairs)
        scores = {p: np.ones(len(r), np.float32) for p, r in rows.items()}
    else:
        t0 = time.perf_counter()
        feats = [_sparse(p, settings) for p in preps]
        t1 = time.perf_counter()
        rows = {}
        glue = None
        if settings.method == "xfeat-lighterglue":
            glue = networks.lighterglue()
        elif settings.method == "disk-lightglue":
            glue = networks.disk_lightglue()
        for i, j in pairs:
            if glue is not None:
                r, s = _glue(glue, feats[i], feats[j], preps[i], preps[j], settings.min_confidence)
            else:
                r, s = _mutual_nn(feats[i], feats[j], settings.min_cosine)
            rows[(i, j)], scores[(i, j)] = r, s
        keypoints = [f.photo_xy for f in feats]
        t_extract, t_match = t1 - t0, time.perf_counter() - t1
    if any(len(r) and (r < 0).any() for r in rows.values()):
        raise MatchError("internal: negative keypoint index in a match")
    return MatchSet(
        keypoints=keypoints,
        matches=rows,
        scores=scores,
        sizes=[p.size for p in preps],
        settings=settings,
        seconds={
            "extract": t_extract,
            "match": t_match,
            "total": time.perf_counter() - start,
        },
    )
