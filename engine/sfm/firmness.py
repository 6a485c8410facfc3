"""Whether each placed photo stands on enough matches: the mapping repeated with a random part
of the verified matches left out.

A photo can be placed with a reprojection error under half a pixel and an orientation spread
under a degree and still hang on a few dozen matches. juicebox_table's second training photo
(a phone capture, 480x270) shares about 110 verified learned matches with each of the other
two, and only 60-78 % of them lie within 2 px of the dataset's epipolar lines (88-95 % between
the other two photos). Matched at the matcher's default 800 px it was placed 0.8° from the
dataset's orientation; matched at 640 px, 3.6° off with an orientation spread of 0.57° (a
confident wrong frame); at 720 or 960 px not at all. In every try below it is lost. DTU's
views, placed by the same matcher, move at most 0.4° in the tries
(docs/experiments/2026-11-30-firm-placement.md).

So the mapping is repeated :data:`TRIES` times, each keeping a random :data:`KEEP_FRACTION` of
every pair's verified matches (seeded, so an estimate is reproducible). A photo that is not
placed in every try, or whose orientation moves by more than :data:`MAX_MOVE_DEG` against the
full solution, is not settled by its photos: the attempt fails naming it, and the next one
is tried.
"""

from __future__ import annotations

import math
import shutil
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from sparsesplat.engine.sfm.align import align, rotation_errors_deg
from sparsesplat.engine.sfm.attempts import Attempt
from sparsesplat.engine.sfm.colmap import require_pycolmap
from sparsesplat.engine.sfm.reconstruct import CameraPrior, Reconstruction, map_database

KEEP_FRACTION = 0.8
"""Share of each pair's verified matches kept in a try."""
TRIES = 4
"""Repeated mappings per estimate."""
MAX_MOVE_DEG = 5.0
"""Largest accepted change of a photo's orientation in a try: the largest rotation error the
estimate is held to. Four neighbouring views of the Blender mic at 400 px, placed within 2°
at the median, move up to 2.2° in a try; the non-firm placements measured also lose photos."""


@dataclass(frozen=True)
class Firmness:
    """How the placed photos fared when the mapping was repeated on fewer matches."""

    tries: int
    """Repeated mappings."""
    unplaced: dict[int, int]
    """Photo index -> tries in which it was not placed (only photos placed in full that some
    try did not place)."""
    moved_deg: dict[int, float]
    """Photo index -> the largest change of its orientation over the tries that placed it,
    after aligning each try to the full solution (degrees; 0 when no try placed it with
    another photo)."""

    def problem(self, names: list[str]) -> str | None:
        """Why the placement is not firm, naming the worst photo; None when it is."""
        if self.unplaced:
            i = max(self.unplaced, key=lambda k: (self.unplaced[k], -k))
            what = f"could not be placed in {self.unplaced[i]} of {self.tries} tries"
        else:
            # nan (a try that could not be aligned) counts as the largest move: no evidence.
            moves = {k: m if math.isfinite(m) else math.inf for k, m in self.moved_deg.items()}
            if not moves or max(moves.values()) <= MAX_MOVE_DEG:
                return None
            i = max(moves, key=lambda k: (moves[k], -k))
            by = f"up to {moves[i]:.1f}°" if math.isfinite(moves[i]) else "an unknown angle"
            what = f"was placed {by} away in another direction (at most {MAX_MOVE_DEG:g}° accepted)"
        return (
            f"photo {i + 1} ({names[i]}) is placed on too few matches: with "
            f"{1 - KEEP_FRACTION:.0%} of the verified matches left out at random it {what}, "
            "so the photos do not settle where it stands and the estimate may be a wrong "
            "frame; add a photo between it and the others, or take the photos closer "
            "together with more overlap"
        )


def thin_database(database: Path, out: Path, keep: float, rng: np.random.Generator) -> Path:
    """A copy of ``database`` at ``out`` keeping each verified match with probability
    ``keep``; returns ``out``."""
    pycolmap = require_pycolmap()
    shutil.copyfile(database, out)
    db = pycolmap.Database.open(str(out))
    try:
        pair_ids, geometries = db.read_two_view_geometries()
        for pair_id, geometry in zip(pair_ids, geometries, strict=True):
            matches = np.asarray(geometry.inlier_matches).reshape(-1, 2)
            if len(matches) == 0:
                continue
            geometry.inlier_matches = np.ascontiguousarray(
                matches[rng.random(len(matches)) < keep], dtype=np.uint32
            )
            a, b = pycolmap.pair_id_to_image_pair(pair_id)
            db.update_two_view_geometry(a, b, geometry)
    finally:
        db.close()
    return out


def firmness(
    database: Path,
    image_dir: Path,
    names: list[str],
    prior: CameraPrior,
    attempt: Attempt,
    rec: Reconstruction,
    threads: int,
    seed: int,
) -> Firmness:
    """Map ``database``'s photos again :data:`TRIES` times on thinned matches
    (:func:`thin_database`) and compare each result with ``rec``, the full solution."""
    placed = sorted(rec.world_to_camera)
    unplaced = dict.fromkeys(placed, 0)
    moved = dict.fromkeys(placed, 0.0)
    for t in range(TRIES):
        rng = np.random.default_rng([seed, t])
        thinned = thin_database(database, database.with_name(f"thinned{t}.db"), KEEP_FRACTION, rng)
        again = map_database(thinned, image_dir, names, prior, attempt, threads, seed)
        both = [i for i in placed if again is not None and i in again.world_to_camera]
        for i in placed:
            if i not in both:
                unplaced[i] += 1
        if again is None or len(both) < 2:
            continue
        est = [again.world_to_camera[i] for i in both]
        full = [rec.world_to_camera[i] for i in both]
        for i, error in zip(both, rotation_errors_deg(est, full, align(est, full)), strict=True):
            if not error <= moved[i]:  # also keeps a nan, which :meth:`Firmness.problem` refuses
                moved[i] = float(error)
    return Firmness(TRIES, {i: n for i, n in unplaced.items() if n}, moved)
