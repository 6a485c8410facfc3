"""The two colour models behind one small interface the trainer and the renderer use.

* :class:`NeuralColor` — DNGaussian's field; global parameters only (hash grid, two MLPs).
* :class:`SHColor` — 3DGS spherical-harmonics colours of degree 0..3 stored per Gaussian.

Only the tensors a configuration uses exist: a degree-0 SH model has no ``sh_rest`` tensor, the
neural model has no per-Gaussian colour tensors at all (the reference drags unused SH tensors
through training; we do not).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import torch
from torch import Tensor, nn

from sparsesplat.engine.color.hashgrid import HashGrid
from sparsesplat.engine.color.neural import NeuralColorField
from sparsesplat.engine.color.sh import C0, eval_sh
from sparsesplat.engine.gaussians import Gaussians


def grown_degree(degree: int, maximum: int, interval: int, position: float, previous: float) -> int:
    """3DGS's band schedule, shared by both colour models: ``degree`` plus one when the step
    from schedule position ``previous`` to ``position`` passes a multiple of ``interval`` (for
    whole iterations: ``position % interval == 0``), at most ``maximum``; unchanged when
    ``interval`` is 0."""
    if interval > 0 and position // interval > previous // interval:
        return min(degree + 1, maximum)
    return degree


class ColorModel:
    """Interface: per-Gaussian colours for one view, plus what the optimizer needs."""

    kind: str = "base"
    """'neural' or 'sh'."""

    def init_per_gaussian(self, n: int, generator: torch.Generator) -> dict[str, Tensor]:
        """Per-Gaussian colour tensors for ``n`` new points (registered in the Gaussians table)."""
        return {}

    def param_groups(self, lrs: dict[str, float]) -> list[dict[str, Any]]:
        """Adam groups for the model's global parameters (named; empty for SH)."""
        return []

    def colors(
        self, gaussians: Gaussians, camera_center: Tensor, rows: Tensor | None = None
    ) -> Tensor:
        """(N, 3) colours for a view from ``camera_center`` (differentiable training path);
        with ``rows`` ((K,) int64 row indices) only the (K, 3) colours of those rows, in order.

        Each Gaussian's colour depends on its own parameters only, so colouring just the rows a
        render uses (DropGaussian's kept ones) gives those rows the same colours and gradients
        and skips the field's work on the rest."""
        raise NotImplementedError

    def color_fn(self, gaussians: Gaussians) -> Callable[[Tensor], Tensor]:
        """A function dirs (N, 3) unit view directions (Gaussian minus camera) → RGB (N, 3),
        with per-Gaussian work cached (used for SH baking at export)."""
        raise NotImplementedError

    def state_dict(self) -> dict[str, Any]:
        """Serializable state of the global parameters and settings."""
        return {"kind": self.kind}

    def step_hook(self, position: float, previous: float) -> None:
        """Called once per training iteration before rendering (SH degree schedule), with the
        iteration's schedule position and the one before (``position - 1`` without a time
        budget)."""


class NeuralColor(ColorModel):
    """DNGaussian's neural colour renderer."""

    kind = "neural"

    def __init__(self, field: NeuralColorField, view_interval: int = 0, view_max: int = 3) -> None:
        """Wrap an already-built field. With ``view_interval`` > 0 the field's view degree
        (the direction bands its colour head sees) grows by one every ``view_interval``
        iterations up to ``view_max`` (:meth:`step_hook`), as 3DGS grows its SH degree."""
        self.field = field
        self.view_interval = view_interval
        self.view_max = view_max

    @classmethod
    def create(
        cls,
        init_means: Tensor,
        generator: torch.Generator,
        log2_table_size: int = 19,
        finest_resolution: int = 2048,
        bound_factor: float = 1.2,
        view_degree: int = 3,
        view_interval: int = 0,
    ) -> NeuralColor:
        """Grid cube centred on the mean of the initial points, half-width
        ``bound_factor`` * (largest axis extent) / 2 (the reference's rule)."""
        center = init_means.mean(dim=0)
        extent = float((init_means.max(dim=0).values - init_means.min(dim=0).values).max())
        bound = max(bound_factor * extent / 2, 1e-12)
        grid = HashGrid(
            log2_table_size=log2_table_size,
            finest_resolution=finest_resolution,
            generator=generator,
        )
        start = 0 if view_interval > 0 else view_degree
        field = NeuralColorField(center, bound, grid=grid, generator=generator, view_degree=start)
        return cls(field, view_interval, view_degree)

    def step_hook(self, position: float, previous: float) -> None:
        """One more view band every ``view_interval`` iterations of the schedule (if set)."""
        self.field.view_degree = grown_degree(
            self.field.view_degree, self.view_max, self.view_interval, position, previous
        )

    def param_groups(self, lrs: dict[str, float]) -> list[dict[str, Any]]:
        """Hash table, sigma MLP and colour MLP as three named groups."""
        f = self.field
        return [
            {"name": "hash_grid", "params": [f.grid.embeddings], "lr": lrs["hash_grid"]},
            {"name": "sigma_mlp", "params": list(f.sigma_mlp.parameters()), "lr": lrs["mlp"]},
            {"name": "color_mlp", "params": list(f.color_mlp.parameters()), "lr": lrs["mlp"]},
        ]

    def colors(
        self, gaussians: Gaussians, camera_center: Tensor, rows: Tensor | None = None
    ) -> Tensor:
        """Full field evaluation; gradients reach the centres through grid and direction."""
        means = gaussians.means if rows is None else gaussians.means.index_select(0, rows)
        return self.field(means, camera_center)

    def geo_features(self, gaussians: Gaussians) -> Tensor:
        """(N, 64) geometry features without grad, to cache for inference."""
        with torch.no_grad():
            return self.field.geo_features(gaussians.means)

    def colors_cached(self, geo: Tensor, means: Tensor, camera_center: Tensor) -> Tensor:
        """Inference path: only the SH direction code and the 2-layer head run per view."""
        with torch.no_grad():
            dirs = nn.functional.normalize(means - camera_center, dim=-1)
            return self.field.colors_from_features(geo, dirs)

    def color_fn(self, gaussians: Gaussians) -> Callable[[Tensor], Tensor]:
        """Neural colours for arbitrary directions, geometry features computed once."""
        geo = self.geo_features(gaussians)

        def fn(dirs: Tensor) -> Tensor:
            with torch.no_grad():
                return self.field.colors_from_features(geo, nn.functional.normalize(dirs, dim=-1))

        return fn

    def state_dict(self) -> dict[str, Any]:
        """Field weights plus the grid layout needed to rebuild it."""
        g = self.field.grid
        return {
            "kind": self.kind,
            "log2_table_size": round(torch.log2(torch.tensor(float(g.table_size))).item()),
            "finest_resolution": _finest_resolution(g),
            "n_levels": g.n_levels,
            "n_features": g.n_features,
            "view_degree": self.field.view_degree,
            "view_interval": self.view_interval,
            "view_max": self.view_max,
            "weights": {k: v.detach().clone() for k, v in self.field.state_dict().items()},
        }

    @classmethod
    def from_state_dict(cls, state: dict[str, Any]) -> NeuralColor:
        """Rebuild from :meth:`state_dict`."""
        grid = HashGrid(
            n_levels=state["n_levels"],
            n_features=state["n_features"],
            log2_table_size=state["log2_table_size"],
            finest_resolution=state["finest_resolution"],
        )
        w = state["weights"]
        # Models saved before view_degree existed saw every band.
        field = NeuralColorField(
            w["center"], float(w["bound"]), grid=grid, view_degree=state.get("view_degree", 3)
        )
        field.load_state_dict(w)
        return cls(field, state.get("view_interval", 0), state.get("view_max", field.view_degree))


def _finest_resolution(grid: HashGrid) -> int:
    """Invert the level-scale rule to recover the configured finest resolution."""
    return round(grid.scales[-1] + 1.0)


class SHColor(ColorModel):
    """Per-Gaussian SH colours of degree 0..3; the active degree grows every ``interval``."""

    kind = "sh"

    def __init__(self, degree: int, interval: int = 1000, active_degree: int = 0) -> None:
        """``degree`` is the maximum; ``active_degree`` the one in use now."""
        if not 0 <= degree <= 3:
            raise ValueError(f"sh_degree must be 0..3, got {degree}")
        self.degree = degree
        self.interval = interval
        self.active_degree = min(active_degree, degree)

    def init_per_gaussian(self, n: int, generator: torch.Generator) -> dict[str, Tensor]:
        """Random base colours as DC coefficients; higher bands (only if degree > 0) at zero."""
        rgb = torch.rand(n, 3, generator=generator)
        out = {"sh_dc": ((rgb - 0.5) / C0).unsqueeze(1)}
        if self.degree > 0:
            out["sh_rest"] = torch.zeros(n, (self.degree + 1) ** 2 - 1, 3)
        return out

    def step_hook(self, position: float, previous: float) -> None:
        """3DGS: one more SH band every ``interval`` iterations of the schedule."""
        self.active_degree = grown_degree(
            self.active_degree, self.degree, self.interval, position, previous
        )

    def _coeffs(self, gaussians: Gaussians) -> Tensor:
        dc = gaussians.params["sh_dc"]
        if "sh_rest" in gaussians.params:
            return torch.cat([dc, gaussians.params["sh_rest"]], dim=1)
        return dc

    def colors(
        self, gaussians: Gaussians, camera_center: Tensor, rows: Tensor | None = None
    ) -> Tensor:
        """3DGS colour: SH evaluated along (mu - camera), + 0.5, clamped at 0."""
        means: Tensor = gaussians.means
        coeffs = self._coeffs(gaussians)
        if rows is not None:
            means, coeffs = means.index_select(0, rows), coeffs.index_select(0, rows)
        dirs = nn.functional.normalize(means - camera_center, dim=-1)
        return eval_sh(coeffs, dirs, self.active_degree)

    def color_fn(self, gaussians: Gaussians) -> Callable[[Tensor], Tensor]:
        """SH colours for arbitrary directions (exact, nothing to bake)."""
        coeffs = self._coeffs(gaussians).detach()

        def fn(dirs: Tensor) -> Tensor:
            return eval_sh(coeffs, nn.functional.normalize(dirs, dim=-1), self.active_degree)

        return fn

    def state_dict(self) -> dict[str, Any]:
        """Degree settings (coefficients live in the Gaussians table)."""
        return {
            "kind": self.kind,
            "degree": self.degree,
            "interval": self.interval,
            "active_degree": self.active_degree,
        }

    @classmethod
    def from_state_dict(cls, state: dict[str, Any]) -> SHColor:
        """Rebuild from :meth:`state_dict`."""
        return cls(state["degree"], state["interval"], state["active_degree"])


def make_color_model(state: dict[str, Any]) -> ColorModel:
    """Rebuild either colour model from its :meth:`ColorModel.state_dict`."""
    if state["kind"] == "neural":
        return NeuralColor.from_state_dict(state)
    if state["kind"] == "sh":
        return SHColor.from_state_dict(state)
    raise ValueError(f"unknown colour model kind {state['kind']!r}")
