"""Training-camera refinement: each training camera's pose (but the first's) corrected by a
small rigid motion learned from the photometric loss.

Cameras estimated from the photos (``engine.sfm``) are off by a few tenths of a degree; at a
focal length of 700 px that is several pixels, so the three views disagree and the model
blurs to average them. Here each camera ``i`` gets a correction ``E_i`` in its own frame (a
rotation about its centre and a shift along its axes, 6 numbers), and trains with the pose
``E_i @ w2c_i``. The first camera keeps its pose: it fixes the frame, so the model stays where
the given cameras put it and renders at the user's poses stay meaningful.

How the gradient reaches ``E_i`` without a pose gradient in the rasterizer: rendering points
``X`` through ``E_i w2c_i`` is rendering ``T_i X`` through ``w2c_i`` with
``T_i = w2c_i^-1 E_i w2c_i`` (a rigid motion of the world), so the photometric pass renders
the Gaussians moved by ``T_i`` (centres ``R_T m + t_T``, rotations ``q_T * q``) through the
camera as given, and autograd carries the loss to the 6 numbers. Every other use of the
camera (the colour field's view direction, the depth passes, densification) sees the refined
camera itself, detached.

A correction is 3 rotation numbers (the vector part of an unnormalised quaternion ``[1, w/2]``,
an angle of about ``|w|`` radians when small, smooth through 0) and 3 translation numbers in
units of the scene extent, trained by their own Adam at a learning rate that decays
log-linearly to 1 % over the run, from ``poses.start`` (a fraction of the schedule: the first
iterations' random Gaussians carry no pose information). A correction beyond
``poses.max_rotation_deg`` is not a refinement any more: the run stops with
:class:`TrainingDiverged` naming the camera, rather than returning a model trained on wrong
poses.
"""

from __future__ import annotations

import math
from typing import Any

import torch
from torch import Tensor

from sparsesplat.engine.camera import Camera
from sparsesplat.engine.errors import TrainingDiverged
from sparsesplat.engine.raster.projection import quat_to_rotmat
from sparsesplat.engine.train.config import PoseConfig
from sparsesplat.engine.train.loop.schedule import ScheduleClock, log_linear

FINAL_LR_FRACTION = 0.01
"""The learning rates decay to this fraction of ``poses.lr`` at the end of the run."""


def quat_multiply(a: Tensor, b: Tensor) -> Tensor:
    """Hamilton product ``a * b`` of wxyz quaternions (broadcasting over leading dims)."""
    aw, ax, ay, az = a.unbind(-1)
    bw, bx, by, bz = b.unbind(-1)
    return torch.stack(
        [
            aw * bw - ax * bx - ay * by - az * bz,
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
        ],
        dim=-1,
    )


def matrix_to_quat(r: Tensor) -> Tensor:
    """(3, 3) rotation matrix to a unit wxyz quaternion (Shepperd's method: the largest of
    the four squared components is taken first, so no branch divides by a small number)."""
    m = r.double()
    trace = m[0, 0] + m[1, 1] + m[2, 2]
    squares = torch.stack([1 + trace, 1 + 2 * m[0, 0] - trace, 1 + 2 * m[1, 1] - trace,
                           1 + 2 * m[2, 2] - trace])  # fmt: skip
    k = int(torch.argmax(squares))
    s = 2 * torch.sqrt(squares[k].clamp_min(1e-300))  # = 4 |q_k|
    if k == 0:
        q = [s / 4, (m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s]
    elif k == 1:
        q = [(m[2, 1] - m[1, 2]) / s, s / 4, (m[0, 1] + m[1, 0]) / s, (m[0, 2] + m[2, 0]) / s]
    elif k == 2:
        q = [(m[0, 2] - m[2, 0]) / s, (m[0, 1] + m[1, 0]) / s, s / 4, (m[1, 2] + m[2, 1]) / s]
    else:
        q = [(m[1, 0] - m[0, 1]) / s, (m[0, 2] + m[2, 0]) / s, (m[1, 2] + m[2, 1]) / s, s / 4]
    out = torch.stack(q)
    return (out / out.norm()).to(r.dtype)


class PoseRefinement:
    """The training cameras' learned corrections (see the module docstring)."""

    def __init__(
        self, settings: PoseConfig, cameras: list[Camera], extent: float, clock: ScheduleClock
    ) -> None:
        """``cameras``: the training cameras as given (float32, on the run's device);
        ``extent``: the scene extent the translations are measured in."""
        self.settings = settings
        self.cameras = cameras
        self.extent = extent
        self.clock = clock
        pose = cameras[0].world_to_camera
        n = len(cameras)
        self.rotation = torch.zeros(n, 3, dtype=pose.dtype, device=pose.device, requires_grad=True)
        """Per camera, the correction's rotation vector (row 0 stays 0: the frame)."""
        self.translation = torch.zeros_like(self.rotation, requires_grad=True)
        """Per camera, the correction's shift along the camera's axes, in scene extents."""
        self.optimizer = torch.optim.Adam(
            [self.rotation, self.translation], lr=0.0, betas=(0.9, 0.999), eps=1e-15
        )
        # Each camera's world-to-camera rotation as a quaternion, for moving the Gaussians'.
        self._view_quats = [matrix_to_quat(c.world_to_camera[:3, :3]) for c in cameras]

    # -- the correction ----------------------------------------------------------------------
    def _correction(self, index: int) -> tuple[Tensor, Tensor, Tensor]:
        """Camera ``index``'s correction as (quaternion (4,), rotation (3, 3), shift (3,)) in
        its camera frame (world units)."""
        half = torch.cat([self.rotation.new_ones(1), self.rotation[index] / 2])
        return half, quat_to_rotmat(half), self.translation[index] * self.extent

    def active(self, position: float) -> bool:
        """Whether the corrections train at schedule ``position``."""
        return position >= self.settings.start * self.clock.total

    def camera(self, index: int) -> Camera:
        """Training camera ``index`` with its current correction (detached)."""
        base = self.cameras[index]
        if index == 0:
            return base
        with torch.no_grad():
            _, r, t = self._correction(index)
            e = torch.eye(4, dtype=base.world_to_camera.dtype, device=r.device)
            e[:3, :3], e[:3, 3] = r, t
            pose = e @ base.world_to_camera
        return Camera(pose, base.fx, base.fy, base.cx, base.cy, base.width, base.height)

    def refined(self) -> list[Camera]:
        """Every training camera with its current correction (detached)."""
        return [self.camera(i) for i in range(len(self.cameras))]

    def move(self, index: int, means: Tensor, quats: Tensor) -> tuple[Tensor, Tensor]:
        """The Gaussians' centres and rotations moved by ``T_index`` (differentiable in the
        correction): rendering them through the camera as given is rendering the originals
        through the refined camera."""
        if index == 0:
            return means, quats
        base = self.cameras[index].world_to_camera
        r_w2c, t_w2c = base[:3, :3], base[:3, 3]
        q_e, r_e, t_e = self._correction(index)
        # T = w2c^-1 E w2c: rotation R^T R_E R, translation R^T (R_E t + t_E - t).
        r_t = r_w2c.T @ r_e @ r_w2c
        t_t = r_w2c.T @ (r_e @ t_w2c + t_e - t_w2c)
        q_view = self._view_quats[index]
        q_inv = q_view * q_view.new_tensor([1.0, -1.0, -1.0, -1.0])
        q_t = quat_multiply(quat_multiply(q_inv, q_e / q_e.norm()), q_view)
        return means @ r_t.T + t_t, quat_multiply(q_t.expand_as(quats), quats)

    # -- the step ----------------------------------------------------------------------------
    def step(self, iteration: int) -> None:
        """The corrections' optimizer step after the photometric backward (when active), and
        the check that each is still a refinement."""
        position = self.clock.position(iteration)
        if not self.active(position):
            self.optimizer.zero_grad(set_to_none=True)
            return
        total = self.clock.total
        start = self.settings.start * total
        lr = log_linear(
            position - start,
            self.settings.lr,
            self.settings.lr * FINAL_LR_FRACTION,
            max(1, round(total - start)),
        )
        for group in self.optimizer.param_groups:
            group["lr"] = lr
        for p in (self.rotation, self.translation):
            if p.grad is not None:
                p.grad[0] = 0.0  # the first camera fixes the frame
        self.optimizer.step()
        self.optimizer.zero_grad(set_to_none=True)
        self.check(iteration)

    def check(self, iteration: int) -> None:
        """Raise :class:`TrainingDiverged` when a correction is non-finite or larger than
        ``poses.max_rotation_deg`` / ``poses.max_translation``."""
        with torch.no_grad():
            for name, p in (("rotation", self.rotation), ("translation", self.translation)):
                if not bool(torch.isfinite(p).all()):
                    raise TrainingDiverged(
                        f"iteration {iteration}: the pose refinement's {name} is not finite"
                    )
            degrees = self.rotation_deg()
            shifts = self.translation.norm(dim=1).tolist()
        for i, (deg, shift) in enumerate(zip(degrees, shifts, strict=True)):
            if deg > self.settings.max_rotation_deg or shift > self.settings.max_translation:
                raise TrainingDiverged(
                    f"iteration {iteration}: training camera {i}'s pose refinement reached "
                    f"{deg:.2f} degrees and {shift:.3f} scene extents (limits "
                    f"{self.settings.max_rotation_deg} and {self.settings.max_translation}): "
                    "the cameras are further off than a refinement can fix; estimate them "
                    "again or switch poses.enabled off"
                )

    def rotation_deg(self) -> list[float]:
        """Per camera, the angle of its correction in degrees."""
        with torch.no_grad():
            half = self.rotation.detach().double() / 2
            return [math.degrees(2 * math.atan(float(v.norm()))) for v in half]

    def summary(self) -> dict[str, list[float]]:
        """Per camera, the correction's angle (degrees) and shift (scene extents), for the
        run's metrics."""
        shifts = self.translation.detach().norm(dim=1).tolist()
        return {
            "rotation_deg": [round(d, 4) for d in self.rotation_deg()],
            "translation_extent": [round(float(s), 5) for s in shifts],
        }

    # -- checkpoints -------------------------------------------------------------------------
    def state_dict(self) -> dict[str, Any]:
        """The corrections and their optimizer's state (the checkpoint's ``poses`` entry)."""
        return {
            "poses": {
                "rotation": self.rotation.detach().cpu().clone(),
                "translation": self.translation.detach().cpu().clone(),
                "optimizer": self.optimizer.state_dict(),
            }
        }

    def load_state_dict(self, state: dict[str, Any]) -> None:
        """Put back what :meth:`state_dict` saved."""
        saved = state["poses"]
        with torch.no_grad():
            self.rotation.copy_(saved["rotation"])
            self.translation.copy_(saved["translation"])
        self.optimizer.load_state_dict(saved["optimizer"])
