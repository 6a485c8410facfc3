"""Per-Gaussian parameters, their activations, random initialization and densification.

Storage follows the engine conventions: means (N, 3) raw, scales as logs (N, 3), quaternions
wxyz (N, 4, normalized on use), opacity as logits (N,). Colour parameters that live per
Gaussian (plain SH colours) are registered in the same table so that densification and
pruning treat every per-Gaussian tensor alike; the neural colour field's parameters are global
and never touched here.

Densification mirrors 3DGS / DNGaussian: clone small Gaussians with a large mean screen-space
gradient, split large ones into ``split_n`` samples with scale / 1.6, prune by opacity. The Adam
moments of every per-Gaussian tensor are cut or zero-extended along with the tensor.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import torch
from torch import Tensor, nn

BASE_PARAMS = ("means", "log_scales", "quats", "opacity_logits")
"""Names of the geometric per-Gaussian parameters every model has."""


def knn_log_scales(means: Tensor, k: int = 3, chunk: int = 4096) -> Tensor:
    """Isotropic initial log-scales: log sqrt(mean squared distance to the ``k`` nearest
    neighbours), squared distance clamped at 1e-7 as simple-knn's ``distCUDA2`` does.

    Computed exactly in chunks so memory stays O(chunk * N)."""
    n = means.shape[0]
    if n == 0:
        return means.new_zeros(0, 3)
    kk = min(k, max(n - 1, 1))
    out = torch.empty(n, dtype=means.dtype, device=means.device)
    for start in range(0, n, chunk):
        block = means[start : start + chunk]
        d2 = torch.cdist(block, means).square_()
        if n > 1:
            # Exclude each point's zero distance to itself.
            idx = torch.arange(start, start + block.shape[0], device=means.device)
            d2[torch.arange(block.shape[0], device=means.device), idx] = float("inf")
        nearest = torch.topk(d2, kk, dim=1, largest=False).values
        nearest = torch.where(torch.isfinite(nearest), nearest, torch.zeros_like(nearest))
        out[start : start + block.shape[0]] = nearest.mean(dim=1)
    # simple-knn clamps at 1e-7 scene units²; relative to the point cloud's size instead, so a
    # rescaled scene gets exactly rescaled Gaussians.
    diag2 = float((means.max(dim=0).values - means.min(dim=0).values).square().sum())
    dist2 = out.clamp_min(1e-7 * max(diag2, 1e-30))
    return torch.log(torch.sqrt(dist2)).unsqueeze(1).repeat(1, 3)


def inverse_sigmoid(x: Tensor) -> Tensor:
    """Logit of ``x`` (the inverse of the opacity activation)."""
    return torch.log(x / (1.0 - x))


class Gaussians:
    """The table of per-Gaussian tensors (all ``nn.Parameter``, same first dimension N)."""

    def __init__(self, params: dict[str, Tensor]) -> None:
        """Wrap ``params`` (must include :data:`BASE_PARAMS`) as leaf parameters."""
        missing = [name for name in BASE_PARAMS if name not in params]
        if missing:
            raise ValueError(f"Gaussians: missing parameters {missing}")
        n = params["means"].shape[0]
        for name, value in params.items():
            if value.shape[0] != n:
                raise ValueError(f"Gaussians: {name} has {value.shape[0]} rows, means has {n}")
        self.params: dict[str, nn.Parameter] = {
            name: nn.Parameter(value.detach().clone().contiguous())
            for name, value in params.items()
        }
        self._reset_stats()

    @classmethod
    def from_points(
        cls, means: Tensor, opacity: float = 0.1, extra: dict[str, Tensor] | None = None
    ) -> Gaussians:
        """Gaussians at ``means`` with kNN isotropic scales, identity rotation and the given
        initial opacity; ``extra`` adds per-Gaussian colour tensors (e.g. SH coefficients)."""
        n = means.shape[0]
        quats = torch.zeros(n, 4, dtype=means.dtype, device=means.device)
        quats[:, 0] = 1.0
        params = {
            "means": means,
            "log_scales": knn_log_scales(means),
            "quats": quats,
            "opacity_logits": inverse_sigmoid(
                torch.full((n,), opacity, dtype=means.dtype, device=means.device)
            ),
        }
        params.update(extra or {})
        return cls(params)

    # -- views and activations -------------------------------------------------------------
    def __len__(self) -> int:
        """Number of Gaussians."""
        return int(self.params["means"].shape[0])

    @property
    def means(self) -> nn.Parameter:
        """(N, 3) centres."""
        return self.params["means"]

    @property
    def log_scales(self) -> nn.Parameter:
        """(N, 3) log of the axis scales."""
        return self.params["log_scales"]

    @property
    def quats(self) -> nn.Parameter:
        """(N, 4) unnormalized wxyz quaternions."""
        return self.params["quats"]

    @property
    def opacity_logits(self) -> nn.Parameter:
        """(N,) opacity logits."""
        return self.params["opacity_logits"]

    @property
    def scales(self) -> Tensor:
        """(N, 3) activated scales (exp)."""
        return torch.exp(self.log_scales)

    @property
    def opacity(self) -> Tensor:
        """(N,) activated opacities (sigmoid)."""
        return torch.sigmoid(self.opacity_logits)

    @property
    def rotations(self) -> Tensor:
        """(N, 4) unit quaternions."""
        return nn.functional.normalize(self.quats, dim=-1)

    # -- densification statistics ----------------------------------------------------------
    def _reset_stats(self) -> None:
        n, device = len(self), self.means.device
        self.grad_accum = torch.zeros(n, device=device)
        """Sum of screen-space gradient norms over the iterations a Gaussian was visible."""
        self.grad_count = torch.zeros(n, device=device)
        """Number of iterations each Gaussian was visible while stats were accumulated."""

    def add_densification_stats(self, grad2d_ndc: Tensor, visible: Tensor) -> None:
        """Accumulate ``|grad2d_ndc|`` (N, 2) for the ``visible`` (N,) bool Gaussians."""
        norms = grad2d_ndc.detach().norm(dim=-1)
        self.grad_accum += torch.where(visible, norms, torch.zeros_like(norms))
        self.grad_count += visible.to(self.grad_count.dtype)

    # -- table surgery ---------------------------------------------------------------------
    def _replace(
        self,
        new_values: dict[str, Tensor],
        optimizer: torch.optim.Optimizer | None,
        state_fn: Callable[[Tensor], Tensor],
    ) -> None:
        """Swap every per-Gaussian parameter for ``new_values[name]`` and transform its Adam
        moments with ``state_fn(old_moment) -> new_moment``."""
        for name, value in new_values.items():
            old = self.params[name]
            new = nn.Parameter(value.detach().contiguous())
            if optimizer is not None:
                for group in optimizer.param_groups:
                    if group["params"] and group["params"][0] is old:
                        state = optimizer.state.pop(old, None)
                        if state is not None:
                            for key in ("exp_avg", "exp_avg_sq"):
                                if key in state:
                                    state[key] = state_fn(state[key]).contiguous()
                            optimizer.state[new] = state
                        group["params"][0] = new
            self.params[name] = new

    def prune(self, keep: Tensor, optimizer: torch.optim.Optimizer | None = None) -> None:
        """Keep only the rows where the (N,) bool mask ``keep`` is true (params, moments, stats)."""
        with torch.no_grad():
            values = {name: p[keep] for name, p in self.params.items()}
            self._replace(values, optimizer, lambda m: m[keep])
            self.grad_accum = self.grad_accum[keep]
            self.grad_count = self.grad_count[keep]

    def append(
        self, rows: dict[str, Tensor], optimizer: torch.optim.Optimizer | None = None
    ) -> None:
        """Append new Gaussians (one tensor per parameter name); their moments start at zero."""
        m = rows["means"].shape[0]
        with torch.no_grad():
            values = {
                name: torch.cat([p, rows[name].to(p)], dim=0) for name, p in self.params.items()
            }

            def extend(moment: Tensor) -> Tensor:
                return torch.cat([moment, moment.new_zeros((m, *moment.shape[1:]))], dim=0)

            self._replace(values, optimizer, extend)
            self.grad_accum = torch.cat([self.grad_accum, self.grad_accum.new_zeros(m)])
            self.grad_count = torch.cat([self.grad_count, self.grad_count.new_zeros(m)])

    def densify_and_prune(
        self,
        optimizer: torch.optim.Optimizer | None,
        grad_threshold: float,
        percent_dense: float,
        scene_extent: float,
        min_opacity: float,
        split_opacity_threshold: float,
        generator: torch.Generator,
        split_n: int = 2,
        max_screen_radius: Tensor | None = None,
        max_screen_size: float | None = None,
        max_world_size: float | None = None,
        max_gaussians: int | None = None,
    ) -> dict[str, int]:
        """One densification step; returns counts {"cloned", "split", "pruned"}.

        Clone where mean grad >= threshold and max scale <= percent_dense * extent, split where
        it is larger; both only for opacity > ``split_opacity_threshold`` (DNGaussian's extra
        gate). Then prune opacity < ``min_opacity`` (and, when given, screen/world-size
        outliers). ``max_gaussians`` caps growth (a CPU safety valve, not in the reference):
        candidates beyond the cap are dropped, largest gradient first kept."""
        with torch.no_grad():
            grads = self.grad_accum / self.grad_count.clamp_min(1.0)
            big = self.scales.max(dim=1).values > percent_dense * scene_extent
            candidates = (grads >= grad_threshold) & (self.opacity > split_opacity_threshold)
            clone_mask = candidates & ~big
            split_mask = candidates & big
            if max_gaussians is not None:
                room = max(0, max_gaussians - len(self))
                wanted = int(clone_mask.sum()) + int(split_mask.sum()) * (split_n - 1)
                if wanted > room:
                    order = torch.argsort(
                        torch.where(candidates, grads, -torch.ones_like(grads)), descending=True
                    )
                    cost = torch.where(split_mask, split_n - 1, 1)[order]
                    allowed = torch.zeros_like(candidates)
                    allowed[order[(torch.cumsum(cost, 0) <= room) & candidates[order]]] = True
                    clone_mask &= allowed
                    split_mask &= allowed
            n_clone, n_split = int(clone_mask.sum()), int(split_mask.sum())

            new_rows: dict[str, Tensor] = {name: p[clone_mask] for name, p in self.params.items()}
            if n_split:
                stds = self.scales[split_mask].repeat(split_n, 1)
                samples = torch.randn(stds.shape, generator=generator, dtype=stds.dtype)
                samples = samples.to(stds.device) * stds
                rot = quat_to_rotmat(self.rotations[split_mask]).repeat(split_n, 1, 1)
                split_rows = {
                    name: p[split_mask].repeat(split_n, *([1] * (p.dim() - 1)))
                    for name, p in self.params.items()
                }
                split_rows["means"] = (
                    torch.bmm(rot, samples.unsqueeze(-1)).squeeze(-1) + split_rows["means"]
                )
                split_rows["log_scales"] = split_rows["log_scales"] - math.log(0.8 * split_n)
                new_rows = {k: torch.cat([new_rows[k], split_rows[k]]) for k in new_rows}
            n_before = len(self)
            if n_clone or n_split:
                self.append(new_rows, optimizer)
            # The split originals are replaced by their samples.
            keep = torch.ones(len(self), dtype=torch.bool, device=self.means.device)
            keep[:n_before] = ~split_mask
            keep &= self.opacity >= min_opacity
            if max_screen_size is not None and max_screen_radius is not None:
                radius = torch.cat(
                    [max_screen_radius, max_screen_radius.new_zeros(len(self) - n_before)]
                ).to(keep.device)
                keep &= radius <= max_screen_size
            if max_world_size is not None:
                keep &= self.scales.max(dim=1).values <= max_world_size
            n_pruned = int((~keep).sum()) - n_split
            self.prune(keep, optimizer)
            self._reset_stats()
        return {"cloned": n_clone, "split": n_split, "pruned": n_pruned}

    def decay_opacity(self, factor: float) -> None:
        """Scale every opacity by ``factor`` in (0, 1] (on the logits, in place, so an
        optimizer's moments stay with their rows)."""
        with torch.no_grad():
            x = self.opacity_logits
            # logit(f p) = log f + log p - log(1 - f p) and log p = x - softplus(x): finite
            # for every float32 x (a plain logit of f * sigmoid(x) gives -inf once p underflows).
            shift = math.log(factor) - nn.functional.softplus(x)
            x.add_(shift - torch.log1p(-factor * torch.sigmoid(x)))

    def reset_opacity(self, optimizer: torch.optim.Optimizer | None, ceiling: float = 0.01) -> None:
        """Clamp opacities to at most ``ceiling`` and zero their Adam moments (3DGS reset)."""
        with torch.no_grad():
            capped = torch.minimum(self.opacity_logits, inverse_sigmoid(torch.tensor(ceiling)))
            self._replace({"opacity_logits": capped}, optimizer, torch.zeros_like)


def quat_to_rotmat(q: Tensor) -> Tensor:
    """(N, 4) unit wxyz quaternions → (N, 3, 3) rotation matrices."""
    w, x, y, z = q.unbind(-1)
    return torch.stack(
        [
            1 - 2 * (y * y + z * z),
            2 * (x * y - w * z),
            2 * (x * z + w * y),
            2 * (x * y + w * z),
            1 - 2 * (x * x + z * z),
            2 * (y * z - w * x),
            2 * (x * z - w * y),
            2 * (y * z + w * x),
            1 - 2 * (x * x + y * y),
        ],
        dim=-1,
    ).reshape(-1, 3, 3)
