"""Binocular self-consistency (Binocular3DGS, NeurIPS'24): the model seen from a virtual camera
beside a training camera, warped back into the training view, must look like the training
photo.

For a training camera with pose [R | t] the virtual camera is the same camera moved by ``d``
along its own x-axis (its centre ``C + d R^T e_x``, so its pose is [R | t - d e_x]); ``d`` is
drawn uniformly in ``[-baseline, baseline] x extent`` each time. The model is rendered there
(colour, with gradient). Each training pixel is lifted by the depth rendered at the training
view (divided by alpha), projected into the virtual camera, and the virtual render is sampled
there (bilinear); the term is the mean L1 difference to the training *photo* over the pixels
whose rendered alpha reaches ``min_alpha`` and that land inside the virtual frame (and, with
``occlusion``, that the virtual camera sees rather than something in front of them). This is
:func:`~sparsesplat.engine.train.regularizers.consistency.warp_consistency_loss` with the
virtual render as the source image: gradients reach the virtual render (the colours and
opacities the model shows from a pose no photo was taken from) and the training view's depth
and alpha. Unlike the warp between two training photos, it covers every pixel of every
training view, also where no other photo overlaps.

The virtual render takes the photometric pass's inputs as they are: the Gaussians DropGaussian
kept that iteration (their opacities compensated) and their colours for the training camera
(a shift of a few hundredths of the extent barely changes the view direction; the colour field
is not evaluated again).
"""

from __future__ import annotations

import torch
from torch import Tensor

from sparsesplat.engine.camera import Camera
from sparsesplat.engine.model.raster import Raster
from sparsesplat.engine.raster import RasterOutput
from sparsesplat.engine.train.config import BinocularConfig
from sparsesplat.engine.train.loop.schedule import ScheduleClock
from sparsesplat.engine.train.regularizers.consistency import seen_depth, warp_consistency_loss

OCCLUSION_TOLERANCE = 0.05
"""Relative depth disagreement beyond which the virtual camera is taken to see something else
(the warp-consistency term's default)."""


def shifted_camera(camera: Camera, shift: float) -> Camera:
    """``camera`` moved by ``shift`` (scene units) along its own x-axis (+x: to its right);
    intrinsics, image size and orientation kept."""
    pose = camera.world_to_camera.clone()
    pose[0, 3] = pose[0, 3] - shift
    return Camera(pose, camera.fx, camera.fy, camera.cx, camera.cy, camera.width, camera.height)


def binocular_loss(
    photo: Tensor,
    virtual_image: Tensor,
    depth: Tensor,
    alpha: Tensor,
    camera: Camera,
    virtual: Camera,
    virtual_depth: Tensor | None = None,
    min_alpha: float = 0.5,
) -> Tensor:
    """Mean L1 difference between the training ``photo`` (3, H, W) and the ``virtual_image``
    (3, H, W, rendered at ``virtual``) warped into ``camera`` through the training render's
    ``depth`` and ``alpha`` (1, H, W); ``virtual_depth`` (H, W): the z the virtual camera sees
    (:func:`seen_depth` of its render; None: no occlusion check). Differentiable in
    ``virtual_image``, ``depth`` and ``alpha``."""
    return warp_consistency_loss(
        photo,
        virtual_image,
        depth,
        camera,
        virtual,
        alpha=alpha,
        source_depth=virtual_depth,
        min_alpha=min_alpha,
        occlusion_tolerance=OCCLUSION_TOLERANCE,
    )


class BinocularConsistency:
    """The trainer's binocular part (hook ``extra_loss``). Stateless apart from the run's
    generator, which draws each shift (so a run without the part draws nothing more)."""

    def __init__(
        self,
        settings: BinocularConfig,
        extent: float,
        raster: Raster,
        generator: torch.Generator,
        clock: ScheduleClock,
    ) -> None:
        """``extent``: the scene extent the baseline is a fraction of; ``clock``: the run's
        schedule position (``start`` and ``until`` follow it)."""
        self.settings = settings
        self.max_shift = settings.baseline * extent
        """The largest shift of the virtual camera, in scene units."""
        self.raster = raster
        self.generator = generator
        self.clock = clock

    def due(self, iteration: int) -> bool:
        """Whether the term applies at ``iteration``."""
        s, position = self.settings, self.clock.position(iteration)
        if position <= s.start or (s.until is not None and position >= s.until):
            return False
        return iteration % s.every == 0

    def extra_loss(
        self,
        iteration: int,
        inputs: tuple[Tensor, ...],
        out: RasterOutput,
        camera: Camera,
        photo: Tensor,
        background: Tensor | None,
    ) -> Tensor | None:
        """``weight x`` :func:`binocular_loss` for the photometric render ``out`` of
        ``inputs`` (the rasterizer's means, log-scales, quaternions, opacity logits, colours)
        through ``camera``, against the training ``photo``; None when the term is not due."""
        if not self.due(iteration):
            return None
        s = self.settings
        draw = float(torch.rand((), generator=self.generator, dtype=torch.float64))
        virtual = shifted_camera(camera, (2.0 * draw - 1.0) * self.max_shift)
        means, log_scales, quats, opacity_logits, colors = inputs
        seen = self.raster(means, log_scales, quats, opacity_logits, colors, virtual, background)
        virtual_depth = None
        if s.occlusion:
            virtual_depth = seen_depth(seen.depth.detach(), seen.alpha.detach())
        loss = binocular_loss(
            photo, seen.image, out.depth, out.alpha, camera, virtual, virtual_depth, s.min_alpha
        )
        return s.weight * loss
