"""Tracks: the keypoints of several photos linked by pairwise matches into one scene point."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sparsesplat.engine.match.result import MatchSet


@dataclass
class Tracks:
    """Observations grouped by track, in flat arrays."""

    track: np.ndarray
    """(O,) int64 track index of each observation (0..T-1), observations sorted by track."""
    view: np.ndarray
    """(O,) int64 photo index of each observation."""
    xy: np.ndarray
    """(O, 2) float64 pixel coordinates of each observation (centres at +0.5)."""
    count: int
    """Number of tracks T."""
    conflicts: int
    """Linked components dropped because they hold two different keypoints of one photo (a
    wrong match somewhere along them)."""

    def lengths(self) -> np.ndarray:
        """(T,) number of photos observing each track."""
        return np.bincount(self.track, minlength=self.count)


def _components(n: int, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Connected-component label (the smallest node id) of each of ``n`` nodes, for the edges
    (a[k], b[k]): minimum-label propagation with pointer jumping."""
    labels = np.arange(n, dtype=np.int64)
    while True:
        low = np.minimum(labels[a], labels[b])
        before = labels.copy()
        np.minimum.at(labels, a, low)
        np.minimum.at(labels, b, low)
        labels = labels[labels]
        if np.array_equal(labels, before):
            return labels


def build_tracks(matches: MatchSet) -> Tracks:
    """Link every pair's matches into tracks; components that see one photo twice are dropped
    (counted in ``conflicts``)."""
    sizes = [len(k) for k in matches.keypoints]
    offset = np.concatenate([[0], np.cumsum(sizes)]).astype(np.int64)
    a_parts, b_parts = [], []
    for (i, j), rows in matches.matches.items():
        if len(rows):
            a_parts.append(offset[i] + rows[:, 0].astype(np.int64))
            b_parts.append(offset[j] + rows[:, 1].astype(np.int64))
    empty = Tracks(np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros((0, 2)), 0, 0)
    if not a_parts:
        return empty
    a, b = np.concatenate(a_parts), np.concatenate(b_parts)
    labels = _components(int(offset[-1]), a, b)
    nodes = np.unique(np.concatenate([a, b]))
    view = np.searchsorted(offset, nodes, side="right") - 1
    roots, track = np.unique(labels[nodes], return_inverse=True)
    # A component that holds two keypoints of one photo is inconsistent.
    per_view = np.unique(np.stack([track, view], axis=1), axis=0)
    distinct = np.bincount(per_view[:, 0], minlength=len(roots))
    total = np.bincount(track, minlength=len(roots))
    good = distinct == total
    keep = good[track]
    renumber = np.cumsum(good) - 1
    track, view, nodes = renumber[track[keep]], view[keep], nodes[keep]
    order = np.argsort(track, kind="stable")
    flat = np.concatenate(matches.keypoints).astype(np.float64).reshape(-1, 2)
    return Tracks(
        track=track[order],
        view=view[order],
        xy=flat[nodes[order]],
        count=int(good.sum()),
        conflicts=int((~good).sum()),
    )
