"""Monocular depth through onnxruntime: the bundled PyDNet++ or any MiDaS / DPT /
Depth-Anything export, described by a small :class:`OnnxModel` record."""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F

from sparsesplat.engine.errors import PriorError
from sparsesplat.engine.priors.base import PriorDepth
from sparsesplat.engine.scene import Scene
from sparsesplat.engine.weights import WeightsNotFound, resolve_weight

IMAGENET_MEAN = (0.485, 0.456, 0.406)
IMAGENET_STD = (0.229, 0.224, 0.225)


@dataclass(frozen=True)
class OnnxModel:
    """How to feed a depth network and read its output."""

    filename: str
    """Default file name, looked up in the models directory (then the bundled weights)."""
    width: int
    """Network input width in pixels (images are resized to width x height, aspect ignored)."""
    height: int
    """Network input height in pixels."""
    layout: str = "NCHW"
    """Input tensor layout: 'NCHW' or 'NHWC'."""
    mean: tuple[float, float, float] = (0.0, 0.0, 0.0)
    """Subtracted from RGB in [0, 1]."""
    std: tuple[float, float, float] = (1.0, 1.0, 1.0)
    """RGB is divided by this after subtracting ``mean``."""
    output: str = "inverse_depth"
    """'inverse_depth' (MiDaS/DPT/DA: larger = nearer, negated here) or 'depth'."""
    output_index: int = 0
    """Which graph output to use."""


MODELS: dict[str, OnnxModel] = {
    # Bundled default: NHWC 640x448, RGB in [0, 1], depth-like output (see weights/PROVENANCE).
    "pydnet": OnnxModel("pydnet_pp_matterport.onnx", 640, 448, "NHWC", output="depth"),
    # The paper's LLFF model (MiDaS v3 DPT-Hybrid): 384 input, mean = std = 0.5 ([-1, 1]).
    "dpt_hybrid": OnnxModel("dpt_hybrid_384.onnx", 384, 384, mean=(0.5,) * 3, std=(0.5,) * 3),
    # The paper's DTU/Blender model (DPT-Large).
    "dpt_large": OnnxModel("dpt_large_384.onnx", 384, 384, mean=(0.5,) * 3, std=(0.5,) * 3),
    "midas_small": OnnxModel(
        "midas_v21_small_256.onnx", 256, 256, "NCHW", IMAGENET_MEAN, IMAGENET_STD
    ),
    "depth_anything_v2_small": OnnxModel(
        "depth_anything_v2_small.onnx", 518, 518, "NCHW", IMAGENET_MEAN, IMAGENET_STD
    ),
}
"""Named descriptions; a user setting is one line such as ``onnx:dpt_hybrid=/path/model.onnx``."""

_SESSIONS: dict[str, Any] = {}


def describe(name: str, overrides: dict[str, str] | None = None) -> OnnxModel:
    """The named description with ``overrides`` applied (size=WxH, layout, output,
    mean=a/b/c, std=a/b/c, output_index)."""
    if name not in MODELS:
        raise PriorError(f"onnx model {name!r} is not described; known: {', '.join(MODELS)}")
    model = MODELS[name]
    for key, value in (overrides or {}).items():
        try:
            if key == "size":
                w, h = (int(x) for x in value.lower().split("x"))
                model = replace(model, width=w, height=h)
            elif key in ("mean", "std"):
                triple = tuple(float(x) for x in value.split("/"))
                if len(triple) != 3:
                    raise ValueError("needs three values a/b/c")
                rgb = (triple[0], triple[1], triple[2])
                model = replace(model, mean=rgb) if key == "mean" else replace(model, std=rgb)
            elif key == "layout" and value.upper() in ("NCHW", "NHWC"):
                model = replace(model, layout=value.upper())
            elif key == "output" and value in ("depth", "inverse_depth"):
                model = replace(model, output=value)
            elif key == "output_index":
                model = replace(model, output_index=int(value))
            else:
                raise ValueError("unknown option or value")
        except ValueError as exc:
            raise PriorError(f"onnx model {name!r}: bad option {key}={value!r} ({exc})") from exc
    return model


def session(path: Path) -> Any:
    """A cached onnxruntime CPU session for ``path``."""
    key = str(path)
    if key not in _SESSIONS:
        import onnxruntime as ort

        if not path.is_file():
            raise PriorError(f"{path}: ONNX model file not found")
        options = ort.SessionOptions()
        options.intra_op_num_threads = max(1, torch.get_num_threads())
        try:
            _SESSIONS[key] = ort.InferenceSession(
                str(path), options, providers=["CPUExecutionProvider"]
            )
        except Exception as exc:  # onnxruntime raises its own untyped errors
            raise PriorError(f"{path}: cannot load ONNX model ({exc})") from exc
    return _SESSIONS[key]


def predict(image: torch.Tensor, model: OnnxModel, path: Path) -> torch.Tensor:
    """Run the network on one (H, W, 3) image in [0, 1]; return (H, W) float32 depth in the
    larger = farther sense, resized (bicubic) back to the image size, on the image's device
    (the network itself runs on the CPU: a GPU render goes there and its depth comes back)."""
    h, w = image.shape[:2]
    x = image.detach().cpu().permute(2, 0, 1)[None].float()
    x = F.interpolate(x, size=(model.height, model.width), mode="bilinear", align_corners=False)
    x = x.clamp(0, 1)
    mean = torch.tensor(model.mean).view(1, 3, 1, 1)
    std = torch.tensor(model.std).view(1, 3, 1, 1)
    x = (x - mean) / std
    if model.layout == "NHWC":
        x = x.permute(0, 2, 3, 1)
    sess = session(path)
    name = sess.get_inputs()[0].name
    try:
        outputs = sess.run(None, {name: np.ascontiguousarray(x.numpy(), dtype=np.float32)})
    except Exception as exc:
        raise PriorError(f"{path}: inference failed ({exc}); check the model description") from exc
    out = torch.from_numpy(np.asarray(outputs[model.output_index], dtype=np.float32))
    out = out.squeeze()
    if out.ndim != 2:
        raise PriorError(f"{path}: expected a single-channel depth output, got {tuple(out.shape)}")
    out = F.interpolate(out[None, None], size=(h, w), mode="bicubic", align_corners=False)[0, 0]
    # Inverse-depth networks: negate the disparity, like the reference (M = 255 - disparity).
    return (-out if model.output == "inverse_depth" else out).to(image.device)


def onnx_priors(
    scene: Scene,
    name: str = "pydnet",
    path: str | Path | None = None,
    overrides: dict[str, str] | None = None,
    models_dir: Path | None = None,
) -> list[PriorDepth]:
    """Monocular priors for every training view with the described network."""
    model = describe(name, overrides)
    if path is None:
        try:
            file = resolve_weight(model.filename, models_dir)
        except WeightsNotFound as exc:
            raise PriorError(
                f"{exc}; for {name!r} give the file in the setting: onnx:{name}=/path/model.onnx"
            ) from exc
    else:
        file = Path(path).expanduser()
    kind = "pydnet" if name == "pydnet" and path is None else f"onnx:{name}"
    out = []
    with torch.no_grad():
        for view in scene.train:
            depth = predict(view.image, model, file)
            valid = torch.isfinite(depth)
            depth = torch.where(valid, depth, torch.zeros_like(depth))
            out.append(PriorDepth(depth, valid.float(), metric=False, kind=kind))
    return out
