"""LLFF near-plane pruning against the spiral render path and at evaluation.

What the reference code does (dngaussian-method.md §1.8, §1.9 "Near/far", §6 item 4; read in
``train_llff.py`` and ``render.py``; not in the paper):

- **Training**: when ``(iteration - 1) % 25 == 0`` and ``iteration > 2000``
  (:meth:`NearPruneSchedule.due`), every Gaussian whose centre is within Euclidean distance
  ``near`` (``--near 10``, absolute dataset units) of *any* of the 180 cameras of the spiral
  render path (``engine/camera_path.py``, kept by the LLFF loader as ``Scene.render_path``) is
  deleted with its optimizer state. It runs after densification, before the photometric Adam
  step.
- **Evaluation**: before rendering the held-out views, Gaussians within ``near`` of any of the
  cameras being rendered are removed (test poses only, no test pixels).

The criterion is a sphere around each camera centre, not a plane: "near-plane" is the
reference's name. ``mode="depth"`` of :func:`near_prune_mask` offers the planar variant
(view-space z in (0, near) for some camera).

Units, where this project differs: the reference's 10 is absolute in the COLMAP units of its 8
LLFF scenes. The shared scenes have near bounds of 1.25 (juicebox_table) and 3.12 (beer_can),
where 10 would delete most of the scene, so the radius here is relative:
``near_prune_radius x Scene.near`` (the nearest scene depth of any image). Nothing real lies
closer to a camera than that bound along its view, so a radius below 1 removes only floaters in
front of the cameras. A scene without a render path (every format but LLFF) prunes against its
training cameras."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, Literal

import torch
from torch import Tensor

from sparsesplat.engine.camera import Camera
from sparsesplat.engine.errors import CameraError
from sparsesplat.engine.gaussians import Gaussians
from sparsesplat.engine.scene import Scene
from sparsesplat.engine.train.config import NearPruneConfig
from sparsesplat.engine.train.loop.densify import ModelCollapsed
from sparsesplat.engine.train.loop.schedule import ScheduleClock


@dataclass(frozen=True)
class NearPruneSchedule:
    """When the training-time prune runs (the reference: every 25 iterations after 2000)."""

    every: int = 25
    """Prune on iterations with ``(iteration - 1) % every == 0``."""
    after: int = 2000
    """... and ``iteration > after``."""

    def due(self, iteration: int, position: float | None = None) -> bool:
        """True when 1-based ``iteration`` prunes (``position``: its schedule position, which
        ``after`` is compared with; None: the iteration itself)."""
        if self.every < 1:
            raise CameraError(f"near prune: every must be >= 1, got {self.every}")
        after = iteration if position is None else position
        return after > self.after and (iteration - 1) % self.every == 0


def near_prune_mask(
    means: Tensor,
    cameras: Sequence[Camera] | Tensor,
    near: float,
    mode: Literal["distance", "depth"] = "distance",
    chunk: int = 65536,
) -> Tensor:
    """(N,) bool: the Gaussians to prune, those closer than ``near`` to any camera.

    ``cameras``: Camera objects, or for ``mode="distance"`` an (M, 3) tensor of centres.
    ``"distance"`` (the reference): Euclidean distance from the centre ``< near``.
    ``"depth"``: view-space z in ``(0, near)`` for some camera (in front of it, before its
    near plane). Distances are computed in float64, so the decision is exact for float32
    means up to float64 rounding. No camera or no Gaussian: nothing to prune."""
    if not (math.isfinite(near) and near >= 0):
        raise CameraError(f"near prune: near must be finite and >= 0, got {near}")
    n = means.shape[0]
    out = torch.zeros(n, dtype=torch.bool, device=means.device)
    if n == 0 or len(cameras) == 0 or near == 0:
        return out
    pts = means.detach().cpu().double()
    if mode == "distance":
        if isinstance(cameras, Tensor):
            centres = cameras.detach().cpu().double().reshape(-1, 3)
        else:
            centres = torch.stack([c.center.detach().cpu().double() for c in cameras])
        for s in range(0, n, chunk):
            # Direct differences, not the |a|^2 + |b|^2 - 2ab shortcut that cancels.
            d = torch.cdist(
                pts[s : s + chunk], centres, compute_mode="donot_use_mm_for_euclid_dist"
            )
            out[s : s + chunk] = (d < near).any(dim=1).to(out.device)
        return out
    if mode != "depth":
        raise CameraError(f"near prune: mode must be 'distance' or 'depth', got {mode!r}")
    if isinstance(cameras, Tensor):
        raise CameraError("near prune: mode 'depth' needs Camera objects (poses), not centres")
    rows = torch.stack([c.world_to_camera.detach().cpu().double()[2] for c in cameras])
    for s in range(0, n, chunk):
        z = pts[s : s + chunk] @ rows[:, :3].T + rows[:, 3]
        out[s : s + chunk] = ((z > 0) & (z < near)).any(dim=1).to(out.device)
    return out


class NearPrune:
    """Deletes the Gaussians near the scene's render path in training and near the rendered
    cameras at evaluation. Hooks: :meth:`step` (after densification, before the photometric
    optimizer step) and :meth:`eval_keep` (the recorder renders only the kept rows)."""

    def __init__(
        self, settings: NearPruneConfig, scene: Scene, clock: ScheduleClock | None = None
    ) -> None:
        """``scene``: its ``near`` sets the radius, its render path (else its training cameras)
        the cameras pruned against in training; ``clock``: the run's schedule position
        (``start`` follows it; None: the iteration itself)."""
        self.settings = settings
        self.schedule = NearPruneSchedule(every=settings.every, after=settings.start)
        """When the training-time prune runs."""
        self.clock = clock
        self.radius = settings.radius * scene.near
        """Prune radius in scene units."""
        path = scene.render_path or [v.camera for v in scene.train]
        self.path_centres = torch.stack([c.center.detach().cpu().double() for c in path])
        """(M, 3) float64 centres of the cameras pruned against in training."""
        self.pruned = 0
        """Gaussians deleted in training so far (reported in the metrics)."""

    def step(self, iteration: int, gaussians: Gaussians, optimizer: torch.optim.Optimizer) -> None:
        """Delete the Gaussians within the radius of a path camera when the schedule is due."""
        position = self.clock.position(iteration) if self.clock is not None else iteration
        if not self.schedule.due(iteration, position) or len(gaussians) == 0:
            return
        drop = near_prune_mask(gaussians.means, self.path_centres, self.radius)
        if bool(drop.all()):
            raise ModelCollapsed(
                f"step {iteration}: near pruning would delete every Gaussian (radius "
                f"{self.radius:.4g} = near_prune.radius {self.settings.radius} x scene near)"
            )
        if bool(drop.any()):
            gaussians.prune(~drop, optimizer)
            self.pruned += int(drop.sum())

    def eval_keep(self, means: Tensor, cameras: Sequence[Camera]) -> Tensor:
        """(N,) bool: the rows an evaluation through ``cameras`` renders."""
        return ~near_prune_mask(means, cameras, self.radius)

    def state_dict(self) -> dict[str, int]:
        """Checkpoint entries."""
        return {"near_pruned": self.pruned}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        """Restore the entries of :meth:`state_dict`."""
        self.pruned = int(state.get("near_pruned", 0))
