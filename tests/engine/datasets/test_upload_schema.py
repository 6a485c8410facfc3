"""The upload folder (``cameras.json``) as the service's loader sees it: one schema, every
mistake from issue #11 a SceneError that names the problem and how to fix it."""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import torch
from PIL import Image

from sparsesplat.engine.camera import Camera
from sparsesplat.engine.datasets import load_scene
from sparsesplat.engine.datasets.common import with_background
from sparsesplat.engine.errors import ConfigError, SceneError
from sparsesplat.engine.synthetic import look_at, make_scene
from sparsesplat.engine.train.config.presets import choose_preset
from tests.cli.scenes import shrink_images, write_object_scene
from tests.engine.datasets.synthetic import write_folder_scene

Meta = dict[str, Any]


def _drop(key: str) -> Callable[[Meta], None]:
    return lambda m: m.pop(key)


def _rename(old: str, new: str) -> Callable[[Meta], None]:
    return lambda m: m.update({new: m.pop(old)})


def _frame_rename(old: str, new: str) -> Callable[[Meta], None]:
    return lambda m: m["frames"][0].update({new: m["frames"][0].pop(old)})


def _translate(frame: int, value: float) -> Callable[[Meta], None]:
    def edit(m: Meta) -> None:
        m["frames"][frame]["matrix"][0][3] = value

    return edit


def _reflect(m: Meta) -> None:
    m["frames"][1]["matrix"][0] = [-x for x in m["frames"][1]["matrix"][0][:3]] + [
        m["frames"][1]["matrix"][0][3]
    ]


def _duplicate(m: Meta) -> None:
    m["frames"][1]["image"] = m["frames"][0]["image"]


def _face_away(m: Meta) -> None:
    # Rotate every camera 180 degrees about its own y axis: each looks straight away from
    # the object (what an OpenGL matrix read as OpenCV does to an inward ring).
    for f in m["frames"]:
        c2w = np.array(f["matrix"])
        c2w[:3, :3] = c2w[:3, :3] @ np.diag([-1.0, 1.0, -1.0])
        f["matrix"] = c2w.tolist()


CASES: list[tuple[str, Callable[[Meta], None], list[str]]] = [
    ("typo convention", _rename("convention", "convension"), ["did you mean 'convention'?"]),
    ("typo pose", _rename("pose", "pos"), ["did you mean 'pose'?"]),
    ("split at top level", lambda m: m.update(spilt="test"), ["did you mean 'split'?"]),
    ("typo split", _frame_rename("split", "spilt"), ["did you mean 'split'?", "frames[0]"]),
    (
        "missing convention",
        _drop("convention"),
        ["missing 'convention'", "'opencv' (+x right, +y down", "'opengl' (+x right, +y up"],
    ),
    ("missing pose", _drop("pose"), ["missing 'pose'", "camera_to_world"]),
    (
        "Blender key",
        _frame_rename("matrix", "transform_matrix"),
        ["unknown field 'transform_matrix'", "did you mean 'matrix'?"],
    ),
    ("duplicate image", _duplicate, ["listed more than once"]),
    ("reflection", _reflect, ["frames[1]", "determinant -1"]),
    (
        "non-rigid",
        lambda m: m["frames"][2]["matrix"][0].__setitem__(0, 3.0),
        ["frames[2]", "not rigid"],
    ),
    ("flat matrix", lambda m: m["frames"][0].update(matrix=[0.0] * 16), ["nest it as 4 rows"]),
    ("3x4 matrix", lambda m: m["frames"][0]["matrix"].pop(), ["add the last row"]),
    ("path escape", lambda m: m["frames"][0].update(image="../x.png"), ["relative path"]),
    ("huge translation", _translate(1, 1e30), ["frame 'r_1.png'", "too large"]),
    ("outlier translation", _translate(2, 1e6), ["frame 'r_2.png'", "median camera position"]),
    ("cameras face away", _face_away, ["no two cameras see a common region", "'convention'"]),
]


@pytest.mark.parametrize(("edit", "needles"), [c[1:] for c in CASES], ids=[c[0] for c in CASES])
def test_folder_loader_names_each_mistake(
    tmp_path: Path, edit: Callable[[Meta], None], needles: list[str]
) -> None:
    root = write_object_scene(tmp_path / "s", "opencv", "camera_to_world", size=24, edit=edit)
    with pytest.raises(SceneError) as info:
        load_scene(root)
    for needle in needles:
        assert needle in str(info.value), str(info.value)
    assert "shape ()" not in str(info.value)


@pytest.mark.parametrize("which", ["held-out", "all"])
def test_tiny_images_are_refused_up_front(tmp_path: Path, which: str) -> None:
    root = write_object_scene(tmp_path / "s", size=24)
    shrink_images(root, which)
    with pytest.raises(SceneError, match=r"image is 1x1 pixels; at least 16x16"):
        load_scene(root)


def test_mistyped_cameras_file_and_bad_json(tmp_path: Path) -> None:
    root = write_folder_scene(tmp_path / "s")
    (root / "cameras.json").write_text('{"convention": "opencv",')
    with pytest.raises(SceneError, match="cannot parse JSON"):
        load_scene(root)
    (root / "cameras.json").unlink()
    with pytest.raises(SceneError, match="unknown scene format"):
        load_scene(root)
    with pytest.raises(SceneError, match=r"cameras\.json: file not found"):
        load_scene(root, format="folder")


def test_conventions_round_trip_with_rgba_on_white(tmp_path: Path) -> None:
    """OpenGL camera-to-world and OpenCV world-to-camera copies of one RGBA capture load to
    the same cameras and the same white-composited targets."""
    gl = load_scene(write_object_scene(tmp_path / "gl", "opengl", "camera_to_world", size=24))
    cv = load_scene(write_object_scene(tmp_path / "cv", "opencv", "world_to_camera", size=24))
    assert torch.equal(gl.background, torch.ones(3)) and torch.equal(cv.background, gl.background)
    for a, b in zip(gl.train + gl.test, cv.train + cv.test, strict=True):
        assert torch.allclose(a.camera.world_to_camera, b.camera.world_to_camera, atol=1e-6)
        assert torch.equal(a.image, b.image)
        assert a.alpha is not None and float(a.alpha.min()) == 0.0
        empty = a.alpha == 0
        assert torch.equal(a.image[empty], torch.ones_like(a.image[empty])), "white background"
    assert gl.near == pytest.approx(cv.near, rel=1e-6) and gl.far == pytest.approx(cv.far, rel=1e-6)
    assert choose_preset(gl) == choose_preset(cv)
    assert choose_preset(gl)[0] == "object"


def test_background_is_one_setting_and_recompositing_is_exact(tmp_path: Path) -> None:
    scene = load_scene(write_object_scene(tmp_path / "s", size=24))
    black = with_background(scene, (0.0, 0.0, 0.0))
    back = with_background(black, (1.0, 1.0, 1.0))
    for v, b, w in zip(scene.train, black.train, back.train, strict=True):
        assert v.alpha is not None
        empty = v.alpha == 0
        assert float(b.image[empty].abs().max()) == 0.0
        assert torch.allclose(w.image, v.image, atol=1e-6)
    # Without alpha the background is black and the images are untouched by a new one.
    plain = load_scene(write_object_scene(tmp_path / "rgb", size=24, alpha=False))
    assert torch.equal(plain.background, torch.zeros(3)) and plain.train[0].alpha is None
    assert torch.equal(with_background(plain, (1, 1, 1)).train[0].image, plain.train[0].image)


def test_preset_choice_follows_alpha_and_backdrop_and_names_the_layout(tmp_path: Path) -> None:
    # The object rendered on black, saved without alpha: a plain black backdrop.
    ring = load_scene(write_object_scene(tmp_path / "ring", size=24, alpha=False))
    name, reason = choose_preset(ring)
    assert name == "object" and "plain black backdrop" in reason and "inward-looking" in reason
    assert torch.equal(ring.background, torch.zeros(3))
    # The same object on white, without alpha: white is detected and becomes the background.
    white = write_object_scene(tmp_path / "white", size=24)
    for f in white.glob("*.png"):
        with Image.open(f) as img:
            flat = Image.new("RGB", img.size, (255, 255, 255))
            flat.paste(img, mask=img.getchannel("A"))
        flat.save(f)
    on_white = load_scene(white)
    assert on_white.train[0].alpha is None and torch.equal(on_white.background, torch.ones(3))
    assert choose_preset(on_white)[0] == "object"
    # write_folder_scene: random textures seen from a 34-degree arc: forward-facing, textured.
    arc = load_scene(write_folder_scene(tmp_path / "arc"))
    name, reason = choose_preset(arc)
    assert name == "default" and "forward-facing" in reason
    assert torch.equal(arc.background, torch.zeros(3))


def test_trainer_targets_and_renders_share_the_configured_background(tmp_path: Path) -> None:
    from sparsesplat.engine.train import Trainer, preset

    scene = load_scene(write_object_scene(tmp_path / "s", size=24))
    small = {"depth_prior": "none", "init_points": 50, "hash_log2_size": 12, "eval_lpips": False}
    for name, rgb in (("black", 0.0), ("white", 1.0), ("gray", 0.5)):
        trainer = Trainer(scene, preset("object", background=name, **small))
        assert torch.equal(trainer.background, torch.full((3,), rgb))
        alpha = scene.train[0].alpha
        assert alpha is not None
        target = trainer.images[0].permute(1, 2, 0)[alpha == 0]
        assert torch.allclose(target, torch.full_like(target, rgb)), name
        assert trainer.background_psnr() is not None
    # The emptiness warning: renders covering under 1% of the pixels are named.
    trainer.view_coverage = {"r_4": 0.0, "r_5": 0.5}
    warning = trainer.emptiness_warning(psnr_db=40.0)
    assert warning is not None and "1 of 2 evaluated views render (nearly) empty" in warning
    assert "r_4" in warning and trainer.emptiness_warning(None) is not None
    trainer.view_coverage = {"r_4": 0.3}
    assert trainer.emptiness_warning(psnr_db=40.0) is None


def test_the_mean_background_is_the_training_photos_mean_colour(tmp_path: Path) -> None:
    """``background="mean"``: one colour, the mean of the training photos (each weighed
    equally, in float64), for targets, renders and the checkpoint; the held-out photos do not
    enter it; every other spelling is refused naming what is accepted."""
    from sparsesplat.engine.model.trained import TrainedModel
    from sparsesplat.engine.train import Trainer, preset

    scene = load_scene(write_folder_scene(tmp_path / "arc"))
    assert scene.test, "the check needs held-out photos that must not count"
    photos = [v.image.double().reshape(-1, 3).mean(dim=0) for v in scene.train]
    expected = torch.stack(photos).mean(dim=0)
    held_out = torch.stack([v.image.double().reshape(-1, 3).mean(dim=0) for v in scene.test])
    assert float((held_out.mean(dim=0) - expected).abs().max()) > 1e-3  # they would differ
    small = {"depth_prior": "none", "init_points": 50, "hash_log2_size": 12, "eval_lpips": False}
    config = preset("default", background=" Mean ", **small)
    assert config.background == "mean"
    trainer = Trainer(scene, config)
    # float32 rounding of a mean of values in [0, 1]: well inside 1e-6
    assert float((trainer.background.double() - expected).abs().max()) < 1e-6
    assert float((trainer.background - torch.zeros(3)).abs().max()) > 0.05  # not black
    state = trainer.state_dict()
    assert torch.equal(TrainedModel(state).background, trainer.background)
    with pytest.raises(ConfigError, match="white, black, gray, mean or 3 numbers"):
        preset("default", background="median")
    with pytest.raises(ConfigError, match="background must be 3 values"):  # built in code
        dataclasses.replace(config, background="median").validate()  # type: ignore[arg-type]


def test_instant_ngp_frames_with_alpha_go_on_white(tmp_path: Path) -> None:
    root = write_object_scene(tmp_path / "ngp", "opengl", "camera_to_world", count=10, size=24)
    meta = json.loads((root / "cameras.json").read_text())
    frames = [
        {"file_path": f["image"], "transform_matrix": f["matrix"], "fl_x": f["fx"],
         "fl_y": f["fy"], "cx": f["cx"], "cy": f["cy"], "w": 24, "h": 24}
        for f in meta["frames"]
    ]  # fmt: skip
    (root / "cameras.json").unlink()
    (root / "transforms.json").write_text(json.dumps({"frames": frames}))
    scene = load_scene(root, views=3)
    assert scene.format == "ngp" and torch.equal(scene.background, torch.ones(3))
    view = scene.train[0]
    assert view.alpha is not None
    assert torch.equal(view.image[view.alpha == 0], torch.ones_like(view.image[view.alpha == 0]))
    assert choose_preset(scene)[0] == "object"


def test_llff_reason_names_the_training_cameras_layout() -> None:
    """The llff preset's init and hard pass follow the training views' layout, so the reason
    the run prints names it (forward-facing here: the synthetic arc spans 29 degrees)."""
    scene = dataclasses.replace(make_scene(seed=0)[0], format="llff")
    name, reason = choose_preset(scene)
    assert name == "llff"
    assert reason.startswith("llff format: the paper's protocol for it; training cameras ")
    assert "forward-facing" in reason
    orbit = [
        dataclasses.replace(v, camera=Camera(look_at(eye, torch.zeros(3)), 30, 30, 16, 12, 32, 24))
        for v, eye in zip(
            scene.train,
            (torch.tensor([-4.0, 0, 0]), torch.tensor([0, 0, -4.0]), torch.tensor([4.0, 0, 0])),
            strict=True,
        )
    ]  # three views 90 degrees apart, all aimed at the origin
    assert "inward-looking" in choose_preset(dataclasses.replace(scene, train=orbit))[1]
