"""The matched-depth term: where a training photo saw a matched, triangulated point, the
rendered depth must be that point's depth.

A track of matches links pixels of two or more training photos; triangulated with the known
cameras it is a 3D point X. If the rendered geometry puts the surface at X along each of those
pixels' rays, the matched pixels land on each other through the rendered depth: this is the
multi-view consistency of the correspondences, written per view against a fixed target (the
triangulation already reconciled the photos, with its reprojection and angle filters). For
view v and its observations (pixel p, point X):

    z = (R_v X + t_v)_z,   d(p) = depth(p) / alpha(p)   (the render's depth is alpha-blended)
    loss_v = mean over p with alpha(p) >= min_alpha of  max(|d(p) / z - 1| - tol(p), 0)

a relative error (the scene's unit cancels) with a dead zone for the triangulation's own
uncertainty: tol(p) = max(tolerance, pixel_error / (f tan a)) for a point triangulated under
the angle a, seen by a camera of focal length f (px). A point from a narrow baseline (a few
degrees, as in a forward-facing capture) constrains the depth loosely, one from a wide one
tightly. It rides on the photometric render of the current view (``RasterOutput.depth``,
``.alpha``), bilinearly sampled at the observations, so it costs a few thousand samples and
their backward: no extra render. Its gradient reaches every parameter the render's depth and
alpha depend on (centres, scales, rotations, opacities).
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import Tensor

from sparsesplat.engine.camera import Camera
from sparsesplat.engine.raster import RasterOutput
from sparsesplat.engine.train.config import CorrespondenceConfig
from sparsesplat.engine.train.init.matched_points import RunMatches
from sparsesplat.engine.train.loop.parts import TrainView
from sparsesplat.engine.train.loop.schedule import ScheduleClock


def sample_at(image: Tensor, xy: Tensor) -> Tensor:
    """(C, K) bilinear samples of ``image`` (C, H, W) at pixel coordinates ``xy`` (K, 2) with
    pixel centres at +0.5 (border pixels repeated beyond the edge); differentiable in
    ``image``."""
    h, w = image.shape[-2:]
    grid = torch.empty_like(xy)
    grid[:, 0] = xy[:, 0] * (2.0 / w) - 1.0
    grid[:, 1] = xy[:, 1] * (2.0 / h) - 1.0
    out = F.grid_sample(
        image[None], grid[None, None], mode="bilinear", padding_mode="border", align_corners=False
    )
    return out[0, :, 0, :]


def matched_depth_loss(
    depth: Tensor,
    alpha: Tensor,
    xy: Tensor,
    target: Tensor,
    tolerance: float | Tensor,
    min_alpha: float,
    max_error: float | None = None,
) -> Tensor | None:
    """The term for one view (module docstring): ``depth`` and ``alpha`` (H, W) or (1, H, W)
    from a render, ``xy`` (K, 2) observation pixels, ``target`` (K,) the points' camera-space
    depths (all > 0), ``tolerance`` the dead zone (one value, or (K,) one per observation),
    ``max_error`` the relative error beyond which an observation is skipped (None: none is).
    None where no observation has enough opacity."""
    h, w = depth.shape[-2:]
    stacked = torch.stack([depth.reshape(h, w), alpha.reshape(h, w)])
    d, a = sample_at(stacked, xy)
    use = a.detach() >= min_alpha
    if not bool(use.any()):
        return None
    relative = (d[use] / a[use]) / target[use] - 1.0
    dead = tolerance[use] if isinstance(tolerance, Tensor) else tolerance
    error = (relative.abs() - dead).clamp_min(0.0)
    if max_error is not None:
        # A truncated loss: the mean stays over the observations with enough opacity, so
        # skipping an outlier does not raise the others' weight.
        error = error * (relative.detach().abs() <= max_error)
    return error.mean()


class CorrespondenceTerm:
    """The matched-depth term of a run (built only when ``correspondence.weight > 0`` and
    the run has matched points). Hook: :meth:`extra_loss` in the photometric pass."""

    def __init__(
        self,
        settings: CorrespondenceConfig,
        matches: RunMatches,
        cameras: list[Camera],
        clock: ScheduleClock,
    ) -> None:
        """Per training view, its observations and their target depths (float32, on the
        cameras' device). Observations behind a camera are dropped (the triangulation keeps
        only points in front of every camera that sees them, so none should be)."""
        self.settings = settings
        self.clock = clock
        points = torch.from_numpy(matches.points).double()
        self.xy: list[Tensor] = []
        """Per view, (K, 2) observation pixels."""
        self.target: list[Tensor] = []
        """Per view, (K,) the observed points' depths in that camera."""
        self.tolerance: list[Tensor] = []
        """Per view, (K,) each observation's dead zone (relative depth)."""
        tan = torch.tan(torch.deg2rad(torch.from_numpy(matches.angles).double()))
        for v, cam in enumerate(cameras):
            rows = torch.from_numpy(matches.view == v)
            idx = torch.from_numpy(matches.point)[rows]
            w2c = cam.world_to_camera.detach().cpu().double()
            z = points[idx] @ w2c[2, :3] + w2c[2, 3]
            front = z > 0
            device = cam.world_to_camera.device
            self.xy.append(torch.from_numpy(matches.xy)[rows][front].float().to(device))
            self.target.append(z[front].float().to(device))
            own = settings.pixel_error / (cam.fx * tan[idx][front]).clamp_min(1e-12)
            self.tolerance.append(own.clamp_min(settings.tolerance).float().to(device))

    @property
    def observations(self) -> int:
        """Observations over every view."""
        return sum(len(t) for t in self.target)

    def extra_loss(self, iteration: int, out: RasterOutput, view: TrainView) -> Tensor | None:
        """``weight x`` the term on this iteration's render of ``view``, or None when the
        schedule is off, the view has no observation or none is opaque enough."""
        s, pos = self.settings, self.clock.position(iteration)
        if pos <= s.start or (s.until is not None and pos >= s.until):
            return None
        target = self.target[view.index]
        if not len(target):
            return None
        i = view.index
        loss = matched_depth_loss(
            out.depth, out.alpha, self.xy[i], target, self.tolerance[i], s.min_alpha, s.max_error
        )
        return None if loss is None else s.weight * loss
