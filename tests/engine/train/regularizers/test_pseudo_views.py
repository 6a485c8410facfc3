"""Depth at pseudo views: the camera between two training cameras (endpoints, midpoint, the
shorter arc), the sideways shift (in the camera's own image plane, within its disc), and the
part in the trainer (not built when off; refused without a monocular prior; its pass moves
only the centres; a run with it stays finite).

Bounds. ``between`` works in float64 and returns the pose in the input's dtype (float32 here),
so an endpoint is reproduced to a few float32 roundings of the pose's entries: 16 unit
roundoffs x the largest entry (the centre enters the translation through one 3x3 product).
"""

from __future__ import annotations

import math

import pytest
import torch

from sparsesplat.engine.camera import Camera
from sparsesplat.engine.errors import ConfigError
from sparsesplat.engine.synthetic import make_scene
from sparsesplat.engine.train import Trainer
from sparsesplat.engine.train.loop.parts import AuxiliaryStep
from sparsesplat.engine.train.regularizers.pseudo_views import between, slerp
from tests.engine.numerics import UNIT_ROUNDOFF
from tests.engine.train.loop.test_trainer_parts import small
from tests.engine.train.plane_scene import camera

U = UNIT_ROUNDOFF


def _angle(r: torch.Tensor) -> float:
    """Rotation angle of a 3x3 rotation matrix (float64), radians."""
    c = (float(torch.trace(r.double())) - 1.0) / 2.0
    return math.acos(max(-1.0, min(1.0, c)))


def _pair() -> tuple[Camera, Camera]:
    a = camera((0.4, -0.2, 0.1), target=(1.0, 0.5, 5.0)).to("cpu", torch.float32)
    b = camera((-1.3, 0.6, 0.4), target=(0.2, -0.4, 6.0)).to("cpu", torch.float32)
    return a, b


def test_between_reproduces_its_endpoints() -> None:
    a, b = _pair()
    for t, end in ((0.0, a), (1.0, b)):
        got = between(a, b, t).world_to_camera
        bound = 16 * U * float(end.world_to_camera.abs().max())
        assert float((got - end.world_to_camera).abs().max()) <= bound


def test_midpoint_is_halfway_in_position_and_angle() -> None:
    """Slerp at 1/2: the rotation from ``a`` to the midpoint is half the rotation from ``a`` to
    ``b``, and equals the one from the midpoint to ``b``; the centre is the mean."""
    a, b = _pair()
    m = between(a, b, 0.5)
    ra, rb, rm = (c.world_to_camera[:3, :3].double() for c in (a, b, m))
    total = _angle(rb @ ra.T)
    assert total > 0.3  # the pair is not trivially close
    assert _angle(rm @ ra.T) == pytest.approx(total / 2, abs=1e-5)
    assert _angle(rb @ rm.T) == pytest.approx(total / 2, abs=1e-5)
    assert float((rm @ rm.T - torch.eye(3, dtype=torch.float64)).abs().max()) < 1e-6
    mid = (a.center.double() + b.center.double()) / 2
    assert float((m.center.double() - mid).abs().max()) < 1e-5


def test_slerp_takes_the_shorter_arc() -> None:
    """q and -q are the same rotation: interpolating towards either gives the same rotation."""
    a = torch.tensor([1.0, 0.0, 0.0, 0.0], dtype=torch.float64)
    b = torch.tensor([0.6, 0.3, -0.5, 0.2], dtype=torch.float64)
    b = b / b.norm()
    p, q = slerp(a, b, 0.3), slerp(a, -b, 0.3)
    assert float((p - q).abs().max()) < 1e-12 or float((p + q).abs().max()) < 1e-12
    assert abs(float(p.norm()) - 1.0) < 1e-12


def _trainer(seed: int, **overrides: object) -> Trainer:
    scene, depths = make_scene(seed=seed)
    return Trainer(scene, small(seed=seed, **{"pseudo.weight": 1.0, **overrides}), depths)


def test_off_is_not_built_and_needs_a_monocular_prior(seed: int) -> None:
    scene, depths = make_scene(seed=seed)
    assert Trainer(scene, small(seed=seed), depths).pseudo is None
    with pytest.raises(ConfigError, match=r"pseudo\.weight"):
        _trainer(seed, **{"depth.prior": "plane_sweep"})


def test_a_shifted_pseudo_camera_moves_in_its_own_image_plane(seed: int) -> None:
    """With ``shift``, the drawn camera is the unshifted one moved within a disc of radius
    shift x extent spanned by its own x and y axes (its orientation unchanged)."""
    t = _trainer(seed, **{"pseudo.shift": 0.5})
    part = t.pseudo
    assert part is not None
    state = t.generator.get_state()
    shifted = part.draw_camera()
    t.generator.set_state(state)
    part.settings = type(part.settings)(weight=1.0, shift=0.0, t_min=part.settings.t_min)
    plain = part.draw_camera()
    r = plain.world_to_camera[:3, :3].double()
    assert torch.equal(shifted.world_to_camera[:3, :3], plain.world_to_camera[:3, :3])
    offset = r @ (shifted.center.double() - plain.center.double())  # in camera axes
    assert abs(float(offset[2])) < 1e-5 * t.extent
    assert 0 < float(offset[:2].norm()) <= 0.5 * t.extent * (1 + 1e-5)


@pytest.mark.parametrize(
    ("mode", "moved"),
    [("hard", {"means"}), ("soft", {"opacity_logits"}), ("full", None)],
)
def test_each_mode_moves_what_it_names(seed: int, mode: str, moved: set[str] | None) -> None:
    """hard: the centres alone (opacities held constant, scales and rotations detached);
    soft: the opacities alone; full: the centres, scales, rotations and opacities."""
    t = _trainer(seed, **{"pseudo.every": 1, "pseudo.mode": mode})
    part = t.pseudo
    assert part is not None
    g = t.gaussians
    before = {k: v.detach().clone() for k, v in g.params.items()}
    view = t._next_view()
    step = AuxiliaryStep(50, g, t.optimizer, view, t.extent, t.guard, t.timer)
    part.step_pre_photometric(step, t.color)
    changed = {k for k, v in g.params.items() if not torch.equal(v.detach(), before[k])}
    geometry = {"means", "log_scales", "quats", "opacity_logits"}
    assert changed == (moved if moved is not None else geometry & set(g.params))


def test_a_run_with_the_part_stays_finite(seed: int) -> None:
    t = _trainer(seed, **{"pseudo.every": 2, "pseudo.shift": 0.5, "pseudo.min_alpha": 0.5})
    res = t.run()
    assert all(bool(torch.isfinite(v).all()) for v in t.gaussians.params.values())
    assert math.isfinite(res.metrics["psnr"])


def test_one_training_camera_gives_that_camera(seed: int) -> None:
    """A run with a single training view still draws: the pseudo camera is that view's."""
    t = _trainer(seed)
    part = t.pseudo
    assert part is not None
    part.cameras = part.cameras[:1]
    drawn = part.draw_camera()
    bound = 16 * U * float(part.cameras[0].world_to_camera.abs().max())
    assert float((drawn.world_to_camera - part.cameras[0].world_to_camera).abs().max()) <= bound
