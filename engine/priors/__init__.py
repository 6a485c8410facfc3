"""Depth priors for the training views: one interface, the kind chosen per scene.

``compute_priors(scene, kind="pydnet", **options)`` returns one :class:`PriorDepth` per
training view (depth larger = farther, confidence in [0, 1], ``metric`` when in scene units).
``kind`` is a one-line setting (see :func:`parse_prior_spec`): ``pydnet`` (bundled ONNX),
``onnx:dpt_hybrid=/path/model.onnx`` (any described MiDaS/DPT/Depth-Anything export),
``user`` (uploaded depth maps), ``plane_sweep`` (stereo between the posed views), ``none``.
"""

from __future__ import annotations

from dataclasses import fields
from pathlib import Path
from typing import Any

from sparsesplat.engine.errors import PriorError
from sparsesplat.engine.priors.base import KINDS, PriorDepth, PriorSpec, parse_prior_spec
from sparsesplat.engine.priors.cache import cache_path, load_cached, save_cached
from sparsesplat.engine.scene import Scene

DEFAULT_PRIOR = "pydnet"
"""Default prior until the trainer's measurements pick one."""


def _sweep_config(options: dict[str, Any]) -> Any:
    from sparsesplat.engine.priors.plane_sweep import SweepConfig

    known = {f.name: f.type for f in fields(SweepConfig)}
    kwargs: dict[str, Any] = {}
    for key, value in options.items():
        if key not in known:
            raise PriorError(f"plane_sweep: unknown option {key!r}; known: {', '.join(known)}")
        try:
            if known[key] in (str, "str | None"):
                kwargs[key] = value
            else:
                kwargs[key] = int(value) if known[key] in (int, "int") else float(value)
        except (TypeError, ValueError) as exc:
            raise PriorError(f"plane_sweep: option {key}={value!r} is not a number") from exc
    return SweepConfig(**kwargs)


def _compute(scene: Scene, spec: PriorSpec, models_dir: Path | None) -> list[PriorDepth]:
    if spec.kind == "none":
        return []
    if spec.kind == "user":
        from sparsesplat.engine.priors.user import user_priors

        return user_priors(scene)
    if spec.kind == "plane_sweep":
        from sparsesplat.engine.priors.plane_sweep import plane_sweep_priors

        return plane_sweep_priors(scene, _sweep_config(spec.options))
    from sparsesplat.engine.priors.onnx_depth import onnx_priors

    if spec.kind == "pydnet":
        return onnx_priors(scene, "pydnet", None, spec.options, models_dir)
    return onnx_priors(scene, spec.model or "", spec.path, spec.options, models_dir)


def compute_priors(
    scene: Scene,
    kind: str = DEFAULT_PRIOR,
    cache_dir: str | Path | None = None,
    models_dir: Path | None = None,
    **options: Any,
) -> list[PriorDepth]:
    """One depth prior per training view of ``scene``.

    Args:
        scene: the loaded scene (priors are computed at the training resolution).
        kind: a prior setting such as ``pydnet``, ``plane_sweep:depths=96`` or
            ``onnx:dpt_hybrid=/models/dpt_hybrid_384.onnx``.
        cache_dir: when given, priors are read from / written to ``.npz`` files there.
        models_dir: where named ONNX files are looked up (default: the models directory).
        **options: extra options merged over those in ``kind`` (e.g. ``depths=96``).
    """
    spec = parse_prior_spec(kind)
    if options:
        merged = {**spec.options, **{k: str(v) for k, v in options.items()}}
        spec = PriorSpec(spec.kind, spec.model, spec.path, merged)
    if spec.kind == "none":
        return []
    setting = repr(spec)
    if cache_dir is not None:
        paths = [cache_path(Path(cache_dir), v, setting) for v in scene.train]
        cached = [load_cached(p) for p in paths]
        if all(c is not None for c in cached):
            return cached  # type: ignore[return-value]
    priors = _compute(scene, spec, models_dir)
    if cache_dir is not None:
        for path, prior in zip(paths, priors, strict=True):
            save_cached(path, prior)
    return priors


__all__ = [
    "DEFAULT_PRIOR",
    "KINDS",
    "PriorDepth",
    "PriorSpec",
    "compute_priors",
    "parse_prior_spec",
]
