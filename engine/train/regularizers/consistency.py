"""A geometric consistency term that needs no model: warp one training photo into another
with the rendered depth, penalise the photometric difference where both views see the surface.

Pixel p of the reference view with rendered depth z(p) is lifted to 3D, projected into the
source view, and the *source photo* is sampled there (bilinear, differentiable in the sample
position). If the rendered geometry is right and the surface is Lambertian, that sample equals
the reference photo at p. The loss is the mean L1 difference over the pixels where

- the reference render is opaque enough to have a depth (``alpha >= min_alpha``; the rendered
  depth is alpha-blended and not normalised, so it is divided by alpha first),
- the point is in front of the source camera and projects between its outermost pixel centres,
- and, when the source view's rendered depth is given, the source sees this point rather than
  something in front of it (``|z_src - depth_src(q)| <= occlusion_tolerance * z_src``).

Gradients reach the rendered depth (and alpha) of the reference view only: the photos are
data, the masks are decisions taken without gradient. It is the self-supervised stereo signal
of sparse-view methods (e.g. the warping losses of CoR-GS / LoopSparseGS) without a flow or
matching network. float32 CPU inputs take one native pass for the value and both gradients
(engine/photometric/cpu/warp.cpp); the torch code below is the reference it is tested against,
and the path for other devices and dtypes.

Where it runs: in the photometric pass, which already renders depth and alpha for the current
view (``RasterOutput.depth``, ``.alpha``); the partner view is another training view (e.g. the
one whose camera centre is nearest). The occlusion check needs the partner's depth, a cheap
depth-only render (features of width 0) without gradient; without it the term also compares
pixels the partner sees occluded. Add ``weight * loss`` to the photometric loss before its
backward::

    loss = photo + cfg.consistency.weight * warp_consistency_loss(
        images[i], images[j], out.depth, cams[i], cams[j], alpha=out.alpha,
        source_depth=partner.depth / partner.alpha.clamp_min(1e-6) (detached, masked))
"""

from __future__ import annotations

import math
from typing import Any

import torch
import torch.nn.functional as F
from torch import Tensor

from sparsesplat.engine.camera import Camera, pixel_rays
from sparsesplat.engine.errors import CameraError
from sparsesplat.engine.gaussians import Gaussians
from sparsesplat.engine.model.raster import Raster
from sparsesplat.engine.photometric import native as photometric_native
from sparsesplat.engine.raster import RasterOutput
from sparsesplat.engine.train.config import ConsistencyConfig
from sparsesplat.engine.train.loop.parts import TrainView
from sparsesplat.engine.train.loop.schedule import ScheduleClock


def relative_pose(reference: Camera, source: Camera) -> tuple[Tensor, Tensor]:
    """Rotation (3, 3) and translation (3,) taking reference-camera points to source-camera
    points, composed in float64 (then the callers' dtype)."""
    rel = source.world_to_camera.detach().double() @ reference.camera_to_world.detach().double()
    if not bool(torch.isfinite(rel).all()):
        raise CameraError("warp: camera poses are not finite")
    return rel[:3, :3], rel[:3, 3]


def warp_coordinates(
    depth: Tensor, reference: Camera, source: Camera
) -> tuple[Tensor, Tensor, Tensor]:
    """Where each reference pixel lands in the source view.

    ``depth`` (H, W): view-space z of the reference pixels. Returns continuous source pixel
    coordinates ``u``, ``v`` (H, W) (pixel centres at +0.5, differentiable in ``depth``) and
    the source-view z (H, W). Where z <= 0 the coordinates are meaningless (masked later)."""
    if tuple(depth.shape) != (reference.height, reference.width):
        raise CameraError(
            f"warp: depth {tuple(depth.shape)} does not match the reference camera "
            f"{reference.height}x{reference.width}"
        )
    rot, trans = relative_pose(reference, source)
    rot, trans = rot.to(depth), trans.to(depth)
    pts = pixel_rays(reference, depth.dtype, depth.device) * depth[..., None]
    q = pts @ rot.T + trans
    z = q[..., 2]
    # Divide only by safe z: a z <= 0 pixel is masked, but its gradient must stay finite.
    safe = torch.where(z > 1e-12, z, torch.ones_like(z))
    u = source.fx * q[..., 0] / safe + source.cx
    v = source.fy * q[..., 1] / safe + source.cy
    return u, v, z


def _sample(image: Tensor, u: Tensor, v: Tensor, camera: Camera, mode: str) -> Tensor:
    """(C, H, W) samples of a (C, Hs, Ws) source map at continuous pixel coordinates."""
    grid = torch.stack([u * (2.0 / camera.width) - 1.0, v * (2.0 / camera.height) - 1.0], -1)
    return F.grid_sample(
        image[None], grid[None], mode=mode, padding_mode="border", align_corners=False
    )[0]


def warp_consistency_loss(
    reference_image: Tensor,
    source_image: Tensor,
    depth: Tensor,
    reference: Camera,
    source: Camera,
    alpha: Tensor | None = None,
    source_depth: Tensor | None = None,
    min_alpha: float = 0.5,
    occlusion_tolerance: float = 0.05,
) -> Tensor:
    """Mean L1 colour difference between the reference photo and the source photo warped to
    it through ``depth`` (see the module docstring for the masks).

    Args:
        reference_image, source_image: (3, H, W) and (3, Hs, Ws) training photos.
        depth: (1, H, W) or (H, W) rendered depth of the reference view (alpha-blended z).
        reference, source: the two cameras.
        alpha: the reference render's (1, H, W) alpha; None means ``depth`` is already z and
            every pixel with finite positive depth counts.
        source_depth: (Hs, Ws) or (1, Hs, Ws) view-space z seen by the source (e.g. its
            render's depth / alpha, detached; non-finite or <= 0 where it sees nothing, which
            passes the check); None skips the occlusion check.
    Returns:
        A scalar, differentiable w.r.t. ``depth`` (and ``alpha``), and w.r.t. ``source_image``
        when it requires a gradient (a render, not a photo: then the torch path runs); 0
        (attached, zero gradient) when no pixel qualifies.
    """
    if not (math.isfinite(min_alpha) and math.isfinite(occlusion_tolerance)):
        raise CameraError("warp: min_alpha and occlusion_tolerance must be finite")
    h, w = reference.height, reference.width
    d = depth.reshape(h, w) if depth.numel() == h * w else depth
    if tuple(reference_image.shape) != (3, h, w):
        raise CameraError(f"warp: reference image {tuple(reference_image.shape)} is not (3, {h}, "
                          f"{w})")  # fmt: skip
    if tuple(source_image.shape) != (3, source.height, source.width):
        raise CameraError(
            f"warp: source image {tuple(source_image.shape)} is not (3, {source.height}, "
            f"{source.width})"
        )
    if tuple(d.shape) != (h, w):
        raise CameraError(
            f"warp: depth {tuple(d.shape)} does not match the reference camera {h}x{w}"
        )
    a = None if alpha is None else alpha.reshape(h, w)
    sd = None
    if source_depth is not None:
        sd = source_depth.detach().reshape(source.height, source.width).to(d)
    # The native pass differentiates the depth and alpha only: a source image with a gradient
    # (the binocular term's render from a virtual camera) takes the torch path.
    needs_source_grad = source_image.requires_grad and torch.is_grad_enabled()
    if not needs_source_grad and photometric_native.warp_l1_suited(
        d, a, reference_image, source_image, sd
    ):
        # One native pass for the value and both gradients (engine/photometric/cpu/warp.cpp).
        rot, trans = relative_pose(reference, source)
        return photometric_native.warp_l1_native(
            d, a, reference_image, source_image, sd,
            (reference.fx, reference.fy, reference.cx, reference.cy),
            (source.fx, source.fy, source.cx, source.cy),
            rot, trans, min_alpha, occlusion_tolerance,
        )  # fmt: skip
    if a is not None:
        valid = (a.detach() >= min_alpha) & torch.isfinite(d.detach())
        z_ref = d / torch.where(valid, a, torch.ones_like(a))
    else:
        z_ref = d
        valid = torch.isfinite(d.detach())
    valid = valid & (z_ref.detach() > 0)
    z_safe = torch.where(valid, z_ref, torch.ones_like(z_ref))
    u, v, z_src = warp_coordinates(z_safe, reference, source)
    # New tensors, not in-place: torch.where above saved ``valid`` for the backward pass.
    with torch.no_grad():
        inside = (u >= 0.5) & (u <= source.width - 0.5) & (v >= 0.5) & (v <= source.height - 0.5)
        valid = valid & (z_src > 0) & inside
        if sd is not None:
            seen = _sample(sd[None], u.detach(), v.detach(), source, "nearest")[0]
            empty = ~torch.isfinite(seen) | (seen <= 0)
            valid = valid & (empty | ((z_src - seen).abs() <= occlusion_tolerance * z_src))
    count = int(valid.sum())
    if count == 0:
        return (z_ref.nan_to_num(0.0) * 0.0).sum()
    warped = _sample(source_image.to(z_ref), u, v, source, "bilinear")
    diff = (warped - reference_image.to(z_ref)).abs().mean(dim=0)
    return diff.masked_fill(~valid, 0.0).sum() / count


def seen_depth(depth: Tensor, alpha: Tensor) -> Tensor:
    """(H, W) view-space z a render sees, from its (1, H, W) alpha-blended ``depth`` and
    ``alpha``: depth / alpha where alpha >= 0.5, else -1 (which passes the occlusion check)."""
    a = alpha[0]
    return torch.where(a >= 0.5, depth[0] / a.clamp_min(1e-6), -1.0)


class WarpConsistency:
    """The trainer's consistency part (hook ``extra_loss``): each training view is paired with
    the other training view whose camera centre is nearest, or with every other training view
    (``partners='all'``; the term is then the mean over them). Its one state, with
    ``partner_depth='last'``: each view's depth from its latest photometric render."""

    def __init__(
        self,
        settings: ConsistencyConfig,
        cameras: list[Camera],
        images: list[Tensor],
        raster: Raster,
        clock: ScheduleClock,
    ) -> None:
        """``cameras``, ``images``: the training views ((3, H, W) photos, not edited targets);
        ``clock``: the run's schedule position (``start`` follows it)."""
        self.settings = settings
        self.clock = clock
        self.cameras = cameras
        self.images = images
        self.raster = raster
        centers = torch.stack([c.center.detach().double().cpu() for c in cameras])
        dist = torch.cdist(centers, centers)
        dist.fill_diagonal_(math.inf)
        others = len(cameras) - 1
        keep = min(1, others) if settings.partners == "nearest" else others
        # Nearest first; a stable sort keeps equal distances in view order.
        self.partners: list[list[int]] = [
            [int(j) for j in torch.sort(dist[i], stable=True).indices[:keep]]
            for i in range(len(cameras))
        ]
        """Partner views of each training view, nearest first (empty with a single view)."""
        self.last_depth: list[Tensor | None] = [None] * len(cameras)
        """``partner_depth='last'``: each view's seen depth (:func:`seen_depth`) from
        its latest photometric render; None until the view is trained with the term on."""

    def state_dict(self) -> dict[str, list[Tensor | None]]:
        """Checkpoint entries: the kept depths (all None unless ``partner_depth='last'``)."""
        return {"consistency_last_depth": [None if d is None else d.cpu() for d in self.last_depth]}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        """Restore the entries of :meth:`state_dict` (absent in older checkpoints: none kept)."""
        kept = state.get("consistency_last_depth")
        if kept is not None and len(kept) == len(self.last_depth):
            device = self.images[0].device if self.images else None
            self.last_depth = [None if d is None else d.to(device) for d in kept]

    def _partner_depth(self, gaussians: Gaussians, partner: int) -> Tensor:
        """View-space z the partner camera sees: its depth kept from its latest photometric
        render (``partner_depth='last'``, once it has one), else a no-gradient depth render."""
        kept = self.last_depth[partner]
        if self.settings.partner_depth == "last" and kept is not None:
            return kept
        g = gaussians
        with torch.no_grad():
            p = self.raster(
                g.means, g.log_scales, g.quats, g.opacity_logits,
                g.means.new_zeros(len(g), 0), self.cameras[partner], None,
            )  # fmt: skip
            return seen_depth(p.depth, p.alpha)

    def extra_loss(
        self, iteration: int, gaussians: Gaussians, out: RasterOutput, view: TrainView
    ) -> Tensor | None:
        """``weight x`` the mean over the partners of :func:`warp_consistency_loss` of the
        photometric render ``out`` against the partner photo, or None when the term is not
        due (or there is no partner)."""
        s, partners = self.settings, self.partners[view.index]
        if self.clock.position(iteration) <= s.start or not partners:
            return None
        if s.occlusion and s.partner_depth == "last":
            # Kept for when this view is another's partner (before its own partners are
            # looked up: a view is never its own partner).
            self.last_depth[view.index] = seen_depth(out.depth.detach(), out.alpha.detach())
        losses = [
            warp_consistency_loss(
                self.images[view.index],
                self.images[j],
                out.depth,
                view.camera,
                self.cameras[j],
                alpha=out.alpha,
                source_depth=self._partner_depth(gaussians, j) if s.occlusion else None,
            )
            for j in partners
        ]
        return s.weight * torch.stack(losses).sum() / len(losses)
