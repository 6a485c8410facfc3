"""A preset's recipe for the training cameras' layout (``presets.LAYOUT_RECIPES``): what it sets,
when it applies, and that the run recipe, the CLI and a job get the same config from it."""

from __future__ import annotations

import dataclasses
import math

import pytest
import torch

from sparsesplat.engine.camera import Camera
from sparsesplat.engine.errors import ConfigError
from sparsesplat.engine.scene import Scene
from sparsesplat.engine.synthetic import look_at, make_scene
from sparsesplat.engine.train.config import TrainConfig
from sparsesplat.engine.train.config.presets import LAYOUT_RECIPES, preset
from sparsesplat.engine.train.run import RunSpec, plan_run, training_layout

FORWARD = "forward-facing"
INWARD = "inward-looking"


def _changed(a: TrainConfig, b: TrainConfig) -> set[str]:
    """Names of the fields where ``a`` and ``b`` differ (dotted for section fields)."""
    out = set()
    for item in dataclasses.fields(a):
        x, y = getattr(a, item.name), getattr(b, item.name)
        if dataclasses.is_dataclass(x):
            fields = dataclasses.fields(x)
            out |= {
                f"{item.name}.{f.name}" for f in fields if getattr(x, f.name) != getattr(y, f.name)
            }
        elif x != y:
            out.add(item.name)
    return out


def _orbit_scene() -> Scene:
    """The synthetic scene with its training cameras moved onto an orbit 80 degrees apart."""
    scene, _ = make_scene(seed=0)
    views = []
    for view, angle in zip(scene.train, (-1.4, 0.0, 1.4), strict=True):
        c = view.camera
        eye = torch.tensor([4.0 * math.sin(angle), 0.0, -4.0 * math.cos(angle)])
        cam = Camera(look_at(eye, torch.zeros(3)), c.fx, c.fy, c.cx, c.cy, c.width, c.height)
        views.append(dataclasses.replace(view, camera=cam))
    return dataclasses.replace(scene, train=views)


def test_the_forward_facing_recipe_is_the_dense_start_and_its_optimizer() -> None:
    length = LAYOUT_RECIPES["llff"][FORWARD]["iterations"]
    assert preset("llff", layout=FORWARD).iterations == length != preset("llff").iterations
    base = preset("llff", length)
    forward = preset("llff", layout=FORWARD)
    assert (base.init.method, base.depth.hard_downscale) == ("auto", None)
    assert (forward.init.method, forward.depth.hard_downscale) == ("dense", 2)
    # the reference's recipe for a start on the surfaces (run_llff_mvs.sh)
    assert forward.optim.lr_means_init == pytest.approx(base.optim.lr_means_init / 32)
    assert forward.optim.lr_means_final == pytest.approx(base.optim.lr_means_final / 32)
    assert forward.densify.grad_threshold == 0.0008
    assert (forward.depth.error_tolerance, forward.optim.lr_scaling) == (0.01, 0.005)
    assert forward.photometric.scale_weight == 0.0
    # what sessions 18-20 measured on top: the warp term, a 70k cap, the SSIM term at 0.8
    assert (forward.consistency.weight, forward.consistency.partner_depth) == (1.0, "last")
    assert (forward.densify.max_gaussians, forward.photometric.lambda_dssim) == (70_000, 0.8)
    assert (base.densify.max_gaussians, base.photometric.lambda_dssim) == (300_000, 0.2)
    # session 35: depth at pseudo views off to the side, in the last third of the run
    p = forward.pseudo
    assert (p.weight, p.mode, p.shift, p.min_alpha) == (1.0, "full", 4.0, 0.5)
    assert p.start == round(forward.iterations * 2 / 3) and not base.pseudo.enabled
    # nothing else differs at the same length (the schedule is compressed the same way; the
    # default length carries the time limit, a length asked for none)
    recipe = set(LAYOUT_RECIPES["llff"][FORWARD]) - {"iterations"}
    assert _changed(base, forward) == recipe | {"time_limit_s"}
    assert preset("default", layout=FORWARD).optim == forward.optim


@pytest.mark.parametrize("name", ["llff", "default"])
def test_the_orbit_recipe_is_the_random_box_with_opacity_decay(name: str) -> None:
    base, orbit = preset(name), preset(name, layout=INWARD)
    assert base.densify.opacity_decay == 1.0 and orbit.densify.opacity_decay == 0.995
    # the same length, init and hard pass as the base recipe; only the decay differs
    assert orbit.iterations == base.iterations
    assert _changed(base, orbit) == {"densify.opacity_decay"}


@pytest.mark.parametrize("name", ["llff", "default", "dtu", "blender", "object"])
def test_a_layout_without_a_recipe_or_an_unknown_one_changes_nothing(name: str) -> None:
    assert preset(name, layout=None) == preset(name)
    assert preset(name, layout="sideways") == preset(name)
    if name in ("dtu", "blender", "object"):
        assert preset(name, layout=FORWARD) == preset(name) == preset(name, layout=INWARD)


@pytest.mark.parametrize("prior", ["none", "plane_sweep", "user", "plane_sweep:levels=32"])
def test_the_recipe_leaves_out_pseudo_views_without_a_monocular_prior(prior: str) -> None:
    """The recipe's pseudo views run the prior's network on renders: with another prior they
    are left out (not refused), while asking for them yourself keeps them (the trainer then
    refuses the run, naming pseudo.weight)."""
    for name in ("llff", "default"):
        assert not preset(name, layout=FORWARD, **{"depth.prior": prior}).pseudo.enabled
        asked = preset(name, layout=FORWARD, **{"depth.prior": prior, "pseudo.weight": 2.0})
        assert asked.pseudo.weight == 2.0
    for network in ("pydnet", "onnx:dpt_hybrid", " ONNX:midas=/m.onnx"):
        assert preset("llff", layout=FORWARD, **{"depth.prior": network}).pseudo.enabled


@pytest.mark.parametrize(
    ("prior", "problem"),
    [("pydnett", "unknown kind"), ("onnx", "needs a model"), ("plane_sweep:levels", "key=value")],
)
def test_a_prior_setting_that_does_not_parse_is_a_config_error_naming_depth_prior(
    prior: str, problem: str
) -> None:
    """The prior setting has one reader (``parse_prior_spec``): the preset is refused with a
    ConfigError that names the field and the reader's reason (not the reader's own error from
    inside the recipe's pseudo-view rule)."""
    with pytest.raises(ConfigError, match=f"depth.prior: prior '{prior}'.*{problem}"):
        preset("llff", layout=FORWARD, **{"depth.prior": prior})
    base = TrainConfig()
    bad = dataclasses.replace(base, depth=dataclasses.replace(base.depth, prior=prior))
    with pytest.raises(ConfigError, match=r"depth\.prior"):
        bad.validate()


def test_naming_the_init_keeps_the_base_recipe_and_overrides_win() -> None:
    for spelling in ("init.method", "init"):  # dotted and the old flat name
        named = preset("llff", layout=FORWARD, **{spelling: "random"})
        assert named == preset("llff", **{"init.method": "random"})
    tuned = preset("llff", layout=FORWARD, **{"optim.lr_means_init": 0.001})
    assert (tuned.optim.lr_means_init, tuned.init.method) == (0.001, "dense")


def test_the_run_recipe_reads_the_layout_of_the_training_cameras() -> None:
    forward_scene, _ = make_scene(seed=0)  # an arc within 29 degrees of the mean view
    orbit_scene = _orbit_scene()
    assert training_layout(forward_scene) == FORWARD
    assert training_layout(orbit_scene) == INWARD
    assert training_layout(None) is None
    spec = RunSpec("llff", {"seed": 2}, iterations=300)
    assert plan_run(spec, forward_scene).config == preset("llff", 300, FORWARD, seed=2)
    assert plan_run(spec, orbit_scene).config == preset("llff", 300, INWARD, seed=2)
    assert plan_run(spec, None).config == preset("llff", 300, seed=2)
    # the default length and a time budget's nominal schedule follow the layout's recipe
    default = RunSpec("llff")
    assert plan_run(default, forward_scene).config == preset("llff", layout=FORWARD)
    assert plan_run(default, orbit_scene).config == preset("llff", layout=INWARD)
    budget = plan_run(RunSpec("llff", time_budget_s=60.0), forward_scene).config
    assert budget.iterations == LAYOUT_RECIPES["llff"][FORWARD]["iterations"]
