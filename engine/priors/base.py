"""The depth-prior result type and the one-line prior setting ("pydnet", "onnx:dpt_hybrid=...")."""

from __future__ import annotations

from dataclasses import dataclass, field

from torch import Tensor

from sparsesplat.engine.errors import PriorError

KINDS = ("pydnet", "onnx", "user", "plane_sweep", "none")
"""Prior kinds :func:`compute_priors` understands."""
MONOCULAR_KINDS = ("pydnet", "onnx")
"""The kinds that are a monocular network, which parts that run the prior on a render of the
model need (``pseudo``)."""


@dataclass
class PriorDepth:
    """A depth prior for one training view, at that view's resolution."""

    depth: Tensor
    """(H, W) float32, larger = farther. Monocular inverse-depth outputs are negated, as the
    reference code does; only ``metric`` priors are in scene units."""
    confidence: Tensor
    """(H, W) float32 in [0, 1]: 0 = invalid / unknown, 1 = trusted."""
    metric: bool
    """True when ``depth`` is view-space z in scene units (plane sweep, user depth)."""
    kind: str = ""
    """The prior kind that produced it (for logs and sheets)."""


@dataclass(frozen=True)
class PriorSpec:
    """A parsed prior setting."""

    kind: str
    """One of :data:`KINDS`."""
    model: str | None = None
    """For ``onnx``: the named model description (e.g. ``dpt_hybrid``)."""
    path: str | None = None
    """For ``onnx``: the model file; None = the description's file in the models directory."""
    options: dict[str, str] = field(default_factory=dict)
    """Extra ``key=value`` options (e.g. ``plane_sweep:depths=64,window=7``)."""

    @property
    def monocular(self) -> bool:
        """Whether the prior is a monocular network (:data:`MONOCULAR_KINDS`)."""
        return self.kind in MONOCULAR_KINDS


def parse_prior_spec(spec: str) -> PriorSpec:
    """Parse a one-line prior setting.

    Forms: ``pydnet`` | ``none`` | ``user`` | ``plane_sweep[:k=v,...]`` |
    ``onnx:NAME=/path/model.onnx`` | ``onnx:NAME`` (file from the models directory) |
    ``onnx:NAME=/path/model.onnx,k=v`` (overrides such as ``size=384x384``).
    """
    text = spec.strip()
    kind, _, rest = text.partition(":")
    kind = kind.strip().lower().replace("-", "_")
    if kind not in KINDS:
        raise PriorError(f"prior {spec!r}: unknown kind {kind!r}; expected one of {KINDS}")
    parts = [p.strip() for p in rest.split(",") if p.strip()] if rest else []
    if kind == "onnx":
        if not parts:
            raise PriorError(f"prior {spec!r}: onnx needs a model, e.g. onnx:dpt_hybrid=FILE")
        name, _, path = parts[0].partition("=")
        options = _options(parts[1:], spec)
        return PriorSpec("onnx", name.strip().lower(), path.strip() or None, options)
    return PriorSpec(kind, None, None, _options(parts, spec))


def _options(parts: list[str], spec: str) -> dict[str, str]:
    out = {}
    for part in parts:
        key, eq, value = part.partition("=")
        if not eq or not key.strip():
            raise PriorError(f"prior {spec!r}: option {part!r} is not key=value")
        out[key.strip()] = value.strip()
    return out
