"""Depth at pseudo views (after FSGS, ECCV'24): the model is rendered from a camera between two
training cameras, the monocular depth network is run on that render, and the render's depth
must follow it under DNGaussian's global-local normalization.

The held-out views that score worst are the ones between the training cameras (flower's
``image008`` and ``image024``), where the three photos' depth priors say nothing directly.
A pseudo view asks the same question there: does the depth the model renders agree with the
shape a monocular network sees in the model's own picture? The pass is DNGaussian's hard
depth pass (opacities held at ``depth.hard_opacity``, scales and rotations detached: only
centres move), at the hard pass's resolution, with its own optimizer step.

The pseudo camera: two distinct training cameras drawn from the run's generator, an
interpolation weight ``t`` uniform in [``t_min``, 1 - ``t_min``]; the centre is interpolated
linearly and the orientation along the shortest rotation between the two (slerp); the
intrinsics and image size are the first camera's.
"""

from __future__ import annotations

import math
from pathlib import Path

import torch
from torch import Tensor

from sparsesplat.engine.camera import Camera
from sparsesplat.engine.color.models import ColorModel
from sparsesplat.engine.errors import ConfigError
from sparsesplat.engine.gaussians import inverse_sigmoid
from sparsesplat.engine.losses import DepthTarget, global_local_depth_loss
from sparsesplat.engine.model.raster import Raster
from sparsesplat.engine.priors.onnx_depth import OnnxModel, predict
from sparsesplat.engine.raster.projection import quat_to_rotmat
from sparsesplat.engine.train.config import DepthConfig, PseudoConfig
from sparsesplat.engine.train.loop.parts import AuxiliaryStep, finish_auxiliary_pass
from sparsesplat.engine.train.loop.poses import matrix_to_quat
from sparsesplat.engine.train.loop.schedule import ScheduleClock
from sparsesplat.engine.train.regularizers.depth_regularizer import downscale_depth
from sparsesplat.engine.train.regularizers.dtu_background import fill_background_depth


def slerp(a: Tensor, b: Tensor, t: float) -> Tensor:
    """Spherical interpolation of unit quaternions ``a`` -> ``b`` (the shorter arc)."""
    dot = float(torch.dot(a, b))
    if dot < 0:
        b, dot = -b, -dot
    if dot > 0.9995:  # nearly equal: linear is exact to rounding and avoids 0/0
        out = a + t * (b - a)
        return out / out.norm()
    theta = math.acos(min(1.0, dot))
    s = math.sin(theta)
    return (math.sin((1 - t) * theta) / s) * a + (math.sin(t * theta) / s) * b


def between(a: Camera, b: Camera, t: float) -> Camera:
    """The camera a fraction ``t`` of the way from ``a`` to ``b`` (centre linear, orientation
    by slerp), with ``a``'s intrinsics and image size."""
    ra, rb = a.world_to_camera[:3, :3].double(), b.world_to_camera[:3, :3].double()
    q = slerp(matrix_to_quat(ra), matrix_to_quat(rb), t)
    r = quat_to_rotmat(q)
    centre = (1 - t) * a.center.double() + t * b.center.double()
    pose = torch.eye(4, dtype=torch.float64)
    pose[:3, :3] = r
    pose[:3, 3] = -r @ centre
    pose = pose.to(a.world_to_camera)
    return Camera(pose, a.fx, a.fy, a.cx, a.cy, a.width, a.height)


def monocular_network(depth: DepthConfig) -> tuple[OnnxModel, Path]:
    """The monocular network of the run's ``depth.prior`` (``pydnet`` or ``onnx:NAME[=FILE]``)
    and its file; ConfigError for a prior that is not one (plane sweep, user depth, none)."""
    from sparsesplat.engine.priors.base import parse_prior_spec
    from sparsesplat.engine.priors.onnx_depth import describe
    from sparsesplat.engine.weights import resolve_weight

    spec = parse_prior_spec(depth.prior)
    if not spec.monocular:
        raise ConfigError(
            f"pseudo.weight > 0 needs a monocular depth prior (pydnet or onnx), got "
            f"depth.prior={depth.prior!r}"
        )
    network = describe("pydnet" if spec.kind == "pydnet" else str(spec.model), spec.options)
    return network, Path(spec.path) if spec.path else resolve_weight(network.filename, None)


class PseudoViewDepth:
    """The pseudo-view depth pass (hook ``step_pre_photometric``, after the depth passes)."""

    def __init__(
        self,
        settings: PseudoConfig,
        depth: DepthConfig,
        cameras: list[Camera],
        raster: Raster,
        generator: torch.Generator,
        clock: ScheduleClock,
        network: OnnxModel,
        network_file: Path,
        background: Tensor,
        hard_downscale: int,
        extent: float = 1.0,
        joint: bool = False,
    ) -> None:
        """``depth``: the run's depth settings (hard opacity, patch range, tolerance, weights);
        ``network`` / ``network_file``: the monocular model of the run's prior."""
        self.settings = settings
        self.depth = depth
        self.cameras = cameras
        self.raster = raster
        self.generator = generator
        self.clock = clock
        self.network = network
        self.network_file = network_file
        self.background = background
        self.downscale = hard_downscale
        self.joint = joint
        self.extent = extent
        self.hard_logit = float(inverse_sigmoid(torch.tensor(depth.hard_opacity)))
        lo, hi = depth.patch_range
        self.patch_range = (-(-lo // hard_downscale), -(-hi // hard_downscale))

    def due(self, iteration: int) -> bool:
        """Whether the pass runs at ``iteration``."""
        s, pos = self.settings, self.clock.position(iteration)
        if pos <= s.start or (s.until is not None and pos >= s.until):
            return False
        return iteration % s.every == 0

    def draw_camera(self) -> Camera:
        """A pseudo camera between two distinct training cameras (the run's generator); with
        a single training camera, that camera (moved by ``shift`` if set)."""
        n = len(self.cameras)
        i = int(torch.randint(n, (1,), generator=self.generator))
        j = i
        if n > 1:
            j = int(torch.randint(n - 1, (1,), generator=self.generator))
            j = j + 1 if j >= i else j
        u = float(torch.rand((), generator=self.generator, dtype=torch.float64))
        t = self.settings.t_min + (1 - 2 * self.settings.t_min) * u
        camera = between(self.cameras[i], self.cameras[j], t)
        if self.settings.shift <= 0:
            return camera
        # A point uniform in the disc: radius sqrt(u) x R, angle uniform.
        r, a = torch.rand(2, generator=self.generator, dtype=torch.float64).unbind()
        radius = math.sqrt(float(r)) * self.settings.shift * self.extent
        angle = 2 * math.pi * float(a)
        pose = camera.world_to_camera.clone()
        # Moving the centre by d along the camera's own axes shifts t by -d (camera frame).
        pose[0, 3] -= radius * math.cos(angle)
        pose[1, 3] -= radius * math.sin(angle)
        return Camera(pose, camera.fx, camera.fy, camera.cx, camera.cy, camera.width, camera.height)

    def step_pre_photometric(self, step: AuxiliaryStep, color: ColorModel) -> None:
        """Render a pseudo view, run the depth network on it and take the hard depth pass
        against that prior, with its own optimizer step."""
        if not self.due(step.iteration):
            return
        g = step.gaussians
        camera = self.draw_camera()
        small = camera if self.downscale == 1 else camera.scaled(1 / self.downscale)
        with torch.no_grad():
            colors = color.colors(g, camera.center, None)
            seen = self.raster(
                g.means, g.log_scales, g.quats, g.opacity_logits, colors, camera, self.background
            )
            image = seen.image.permute(1, 2, 0).clamp(0, 1)
            prior = predict(image, self.network, self.network_file)
            # Pixels the model leaves (nearly) empty there show the background, whose depth
            # neither the render nor the network can know: both are filled with their means.
            coverage = seen.alpha.reshape(camera.height, camera.width).float()
            if self.downscale > 1:
                size = (small.height, small.width)
                prior, coverage = downscale_depth(prior, size), downscale_depth(coverage, size)
            holes = coverage < self.settings.min_alpha
        step.timer.tick("pseudo_prior")
        n = len(g)
        empty = g.means.new_zeros(n, 0)
        mode = self.settings.mode
        args: tuple[Tensor, Tensor, Tensor, Tensor]
        if mode == "hard":
            hard = torch.full((n,), self.hard_logit, device=g.means.device)
            args = (g.means, g.log_scales.detach(), g.quats.detach(), hard)
        elif mode == "soft":
            args = (g.means.detach(), g.log_scales.detach(), g.quats.detach(), g.opacity_logits)
        else:
            args = (g.means, g.log_scales, g.quats, g.opacity_logits)
        means, log_scales, quats, opacity = args
        out = self.raster(means, log_scales, quats, opacity, empty, small, None)
        d = out.depth.reshape(small.height, small.width)
        if self.settings.min_alpha > 0:
            d, prior = fill_background_depth(d, prior, holes)
        s = self.depth
        loss = self.settings.weight * global_local_depth_loss(
            d,
            DepthTarget(prior),
            self.patch_range,
            s.error_tolerance,
            self.generator,
            s.global_weight,
            s.local_weight,
        )
        finish_auxiliary_pass(step, loss, "the pseudo-view depth loss", self.joint)
        step.timer.tick("pseudo_depth")
