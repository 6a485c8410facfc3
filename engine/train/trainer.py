"""The DNGaussian trainer: sparse-view 3DGS with hard/soft depth and Global-Local normalization.

One iteration follows the reference code (dngaussian-method.md §1.6): up to three separate
forward/backward passes, each followed by its own step of ONE shared Adam optimizer
(``zero_grad(set_to_none=True)`` in between, so a pass only moves the tensors it reaches):

1. hard depth: opacity 0.95 everywhere, scales/rotations detached → only centres move;
2. soft depth (after ``soft_depth_start``): centres/scales/rotations detached → only opacities;
3. photometric: L1 + λ·D-SSIM + shape/scale/opacity regularizers → everything; densification.

Deviations from the reference, on purpose: guarded depth loss (empty selection, zero variance),
no unused SH tensors, geometry features cached per evaluation, a fixed hash-grid resolution
(scale-free), an optional cap on the number of Gaussians, no LLFF spiral near-plane pruning and
no DTU/Blender scene-name hacks.

No global state: each trainer owns its torch.Generator, optimizer and models.
"""

from __future__ import annotations

import json
import logging
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import torch
from torch import Tensor

from sparsesplat.engine.camera import Camera
from sparsesplat.engine.color.models import ColorModel, NeuralColor, SHColor, make_color_model
from sparsesplat.engine.datasets.common import with_background
from sparsesplat.engine.errors import EngineError, SceneError, TrainingDiverged
from sparsesplat.engine.gaussians import Gaussians, inverse_sigmoid
from sparsesplat.engine.losses import (
    SSIMTarget,
    edge_aware_smoothness,
    global_local_depth_loss,
    opacity_regularizer,
    photometric_loss,
    scale_regularizer,
    shape_regularizer,
)
from sparsesplat.engine.metrics.image import masked_psnr, psnr, quantize
from sparsesplat.engine.raster import RasterOutput, rasterize
from sparsesplat.engine.scene import Scene
from sparsesplat.engine.train.checkpoint import CHECKPOINT_NAME, load_checkpoint, save_checkpoint
from sparsesplat.engine.train.config import TrainConfig
from sparsesplat.engine.train.evaluate import PSNR_CEILING, Evaluator
from sparsesplat.engine.train.progress import (
    ProgressCallback,
    ProgressRecord,
    StateChange,
    wants_stop,
)
from sparsesplat.engine.train.schedule import position_lr

log = logging.getLogger(__name__)


class ModelCollapsed(EngineError, RuntimeError):
    """Training removed every Gaussian (e.g. a pruning threshold no Gaussian can pass)."""


@dataclass
class TrainResult:
    """What a finished (or cleanly stopped) run returns."""

    metrics: dict[str, Any]
    """Final held-out metrics (psnr, ssim, lpips, avge; None where unavailable) plus seconds,
    iterations, n_gaussians and, for neural colour, the SH baking PSNR."""
    artifacts: dict[str, Path]
    """Written files by kind: checkpoint, metrics, series_json/csv/png, ply, splat."""
    seconds: float
    """Training seconds (evaluation and checkpoint time excluded)."""
    n_gaussians: int
    """Gaussians at the end."""
    records: list[dict[str, Any]] = field(default_factory=list)
    """The error-vs-time series (ProgressRecord dicts)."""
    stopped: bool = False
    """True when the progress callback asked the run to stop before the last iteration."""
    iteration: int = 0
    """Iterations completed."""


def _frusta_box(scene: Scene) -> tuple[Tensor, Tensor]:
    """A box around the training frusta between the scene's near and far bounds."""
    pts = []
    far = min(scene.far, scene.near * 1e3) if scene.near > 0 else scene.far
    for v in scene.train:
        cam = v.camera
        c2w = cam.camera_to_world.float()
        for u, w in ((0, 0), (cam.width, 0), (0, cam.height), (cam.width, cam.height)):
            ray = torch.tensor([(u - cam.cx) / cam.fx, (w - cam.cy) / cam.fy, 1.0])
            for z in (scene.near, far):
                pts.append(c2w[:3, :3] @ (ray * z) + c2w[:3, 3])
    p = torch.stack(pts)
    return p.min(dim=0).values, p.max(dim=0).values


def _empty_background_to_nearest(prior: Tensor, image: Tensor, background: Tensor) -> Tensor:
    """``prior`` (H, W) with the pixels where ``image`` (3, H, W) equals ``background`` to
    within half an 8-bit step set to the prior's smallest (nearest) value elsewhere."""
    empty = ((image - background.view(3, 1, 1)).abs() <= 0.5 / 255).all(dim=0)
    if not bool(empty.any()) or bool(empty.all()):
        return prior
    return torch.where(empty, prior[~empty].min(), prior)


def initial_point_count(
    cfg: TrainConfig, lo: Tensor, hi: Tensor, camera_centers: list[Tensor]
) -> int:
    """The automatic initial Gaussian count: ``init_points_density`` x the init box's largest
    side over the median distance from the cameras to the box centre (a ratio of lengths, so
    the same scene in millimetres or metres gets the same count), clamped to the config's
    bounds."""
    centre = (lo.double() + hi.double()) / 2
    dist = torch.stack([(c.double() - centre).norm() for c in camera_centers]).median()
    side = float((hi.double() - lo.double()).max())
    n = round(cfg.init_points_density * side / float(dist)) if float(dist) > 0 else 0
    return min(max(n, cfg.init_points_min), cfg.init_points_max)


BACKGROUND_MARGIN_DB = 0.5
"""A held-out PSNR within this of the constant-background image's is no better than an empty
model (the run warns)."""
EMPTY_COVERAGE = 0.01
"""A render whose mean alpha is below this is (nearly) empty."""


def json_safe(value: Any) -> Any:
    """``value`` with every non-finite float replaced by None (JSON has no Infinity/NaN)."""
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, dict):
        return {k: json_safe(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [json_safe(v) for v in value]
    return value


class Trainer:
    """Trains one scene with one config; drive it with :meth:`run`."""

    def __init__(
        self,
        scene: Scene,
        config: TrainConfig,
        priors: list[Any] | None = None,
        out_dir: str | Path | None = None,
        on_progress: ProgressCallback | None = None,
        device: str | torch.device = "cpu",
        resume_from: str | Path | None = None,
    ) -> None:
        """Set up the model. ``priors``: one PriorDepth (or (H, W) tensor) per training view, or
        None when the config uses no depth. ``resume_from``: a checkpoint to continue."""
        self.config = config.validate()
        self.scene = scene
        self.device = torch.device(device)
        self.out_dir = Path(out_dir) if out_dir is not None else None
        self.on_progress = on_progress
        if not scene.train:
            raise SceneError(f"scene {scene.name!r}: no training views")
        self.generator = torch.Generator().manual_seed(config.seed)
        self._setup_data(priors)
        self._setup_model()
        self.iteration = 0
        self.elapsed_s = 0.0
        self.records: list[dict[str, Any]] = []
        self.view_stack: list[int] = []
        self.hard_ema: float | None = None
        self._step_ema: dict[str, float] = {}
        self.timings: dict[str, float] = {}
        """Accumulated seconds per stage when ``config.profile`` is on."""
        self._loss_sum = 0.0
        self._loss_count = 0
        self._background_psnr: float | None = None
        self.view_coverage: dict[str, float] = {}
        """Mean alpha of each view's render at the last evaluation (by view name)."""
        self.stop_requested = False
        """Set from another thread (a job's cancel or a time budget): the run stops after the
        current iteration, with a checkpoint, as if the progress callback had said stop."""
        if resume_from is not None:
            self._load_state(load_checkpoint(resume_from))

    # -- setup -----------------------------------------------------------------------------
    def _setup_data(self, priors: list[Any] | None) -> None:
        cfg, dev = self.config, self.device
        bg = cfg.background if cfg.background is not None else self.scene.background
        # One background for targets and renders: images with alpha are re-composited on it.
        self.scene = with_background(self.scene, torch.as_tensor(bg, dtype=torch.float32))
        self.background = self.scene.background.float().reshape(3).to(dev)
        self.cameras = [v.camera.to(dev, torch.float32) for v in self.scene.train]
        self.images = [
            v.image.permute(2, 0, 1).contiguous().float().to(dev) for v in self.scene.train
        ]
        # The targets' SSIM statistics are fixed: computed once, not every iteration.
        self.ssim_targets = [SSIMTarget(img) for img in self.images]
        self.priors: list[Tensor] | None = None
        self.smooth_guides: list[Tensor] | None = None
        if cfg.uses_depth:
            if priors is None or len(priors) != len(self.scene.train):
                got = "none" if priors is None else str(len(priors))
                raise SceneError(
                    f"priors: depth_prior={cfg.depth_prior!r} needs one prior per training view "
                    f"({len(self.scene.train)}), got {got}"
                )
            self.priors, self.smooth_guides = [], []
            for i, p in enumerate(priors):
                d = torch.as_tensor(getattr(p, "depth", p), dtype=torch.float32).to(dev)
                h, w = self.images[i].shape[1:]
                if d.shape[-2:] != (h, w) or not bool(torch.isfinite(d).all()):
                    raise SceneError(
                        f"priors[{i}]: depth must be finite ({h}, {w}) for view "
                        f"{self.scene.train[i].name!r}, got shape {tuple(d.shape)}"
                    )
                d = d.reshape(h, w)
                if cfg.depth_empty_background:
                    d = _empty_background_to_nearest(d, self.images[i], self.background)
                self.priors.append(d)
                # The reference's smoothness weights see the prior on a [0, 257] scale.
                span = float(d.max() - d.min())
                self.smooth_guides.append((d - d.min()) / span * 257.0 if span > 0 else d * 0)
        centers = torch.stack([c.center.float() for c in self.cameras])
        radius = float((centers - centers.mean(dim=0)).norm(dim=1).max()) * 1.1
        if cfg.init_box is not None:
            lo, hi = (torch.tensor(c, dtype=torch.float32) for c in cfg.init_box)
        elif self.scene.init_box is not None:
            lo, hi = (torch.tensor(c, dtype=torch.float32) for c in self.scene.init_box)
        else:
            lo, hi = _frusta_box(self.scene)
        self.box = (lo.cpu(), hi.cpu())
        if radius <= 0:  # a single view (or coincident cameras): fall back to the box size
            radius = float((hi - lo).max()) * 0.5
        self.extent = radius
        near = cfg.raster_near if cfg.raster_near is not None else 0.2 * self.scene.near
        self.raster_near = near if near > 0 else 0.01
        """View-z culling distance used by every render of this run."""
        """Scene extent (1.1 x max train-camera distance from their mean), scales LRs."""

    def _setup_model(self) -> None:
        cfg, g = self.config, self.generator
        lo, hi = self.box
        if cfg.init_points is not None:
            n = cfg.init_points
        else:
            n = initial_point_count(cfg, lo, hi, [c.center.cpu() for c in self.cameras])
        points = lo + torch.rand(n, 3, generator=g) * (hi - lo)
        self.color: ColorModel
        if cfg.color_model == "neural":
            self.color = NeuralColor.create(
                points,
                g,
                log2_table_size=cfg.hash_log2_size,
                finest_resolution=cfg.hash_finest_resolution,
            )
            self.color.field.to(self.device)
        else:
            self.color = SHColor(cfg.sh_degree, cfg.sh_degree_interval)
        extra = self.color.init_per_gaussian(n, g)
        self.gaussians = Gaussians.from_points(
            points.to(self.device),
            cfg.init_opacity,
            {k: v.to(self.device) for k, v in extra.items()},
        )
        self.optimizer = self._make_optimizer()

    def _make_optimizer(self) -> torch.optim.Adam:
        cfg = self.config
        lrs = {
            "means": cfg.lr_means_init * self.extent,
            "log_scales": cfg.lr_scaling,
            "quats": cfg.lr_rotation,
            "opacity_logits": cfg.lr_opacity,
            "sh_dc": cfg.lr_sh,
            "sh_rest": cfg.lr_sh / 20.0,
        }
        groups: list[dict[str, Any]] = [
            {"name": name, "params": [p], "lr": lrs[name]}
            for name, p in self.gaussians.params.items()
        ]
        groups += self.color.param_groups({"hash_grid": cfg.lr_hash_grid, "mlp": cfg.lr_mlp})
        # fused: one kernel per tensor, several times faster than the default on CPU (the hash
        # table is millions of entries) and deterministic, so resumed runs stay bit-identical.
        return torch.optim.Adam(groups, lr=0.0, eps=cfg.adam_eps, fused=True)

    # -- rendering ---------------------------------------------------------------------------
    def _raster(
        self,
        means: Tensor,
        log_scales: Tensor,
        quats: Tensor,
        opacity: Tensor,
        feats: Tensor,
        cam: Camera,
        bg: Tensor | None,
    ) -> RasterOutput:
        cfg = self.config
        return rasterize(
            means,
            log_scales,
            quats,
            opacity,
            feats,
            cam,
            bg,
            near=self.raster_near,
            eps2d=cfg.eps2d,
            backend=cfg.raster_backend,
        )

    def render(self, camera: Camera, background: Tensor | None = None) -> RasterOutput:
        """Render the current model through ``camera`` without gradients."""
        with torch.no_grad():
            return _render_model(
                self.gaussians,
                self.color,
                camera.to(self.device, torch.float32),
                self.background if background is None else background,
                self._raster,
                None,
            )

    # -- progress ----------------------------------------------------------------------------
    def _emit(self, event: ProgressRecord | StateChange) -> bool:
        if self.on_progress is None:
            return False
        return wants_stop(self.on_progress(event))

    def evaluate(self, max_views: int | None = None) -> dict[str, float | None]:
        """Mean held-out metrics (all None when the scene has no held-out views)."""
        views = self.scene.test
        if max_views is not None and len(views) > max_views:
            # Evenly spaced, so an interim curve samples the whole held-out trajectory.
            picks = torch.linspace(0, len(views) - 1, max(1, max_views)).round().long()
            views = [views[int(i)] for i in picks.unique()]
        if not views:
            return {"psnr": None, "ssim": None, "lpips": None, "avge": None}
        if not hasattr(self, "_evaluator"):
            self._evaluator = Evaluator(self.config.eval_lpips)
        geo = (
            self.color.geo_features(self.gaussians) if isinstance(self.color, NeuralColor) else None
        )
        scores = []
        coverage = []
        with torch.no_grad():
            for v in views:
                out = _render_model(
                    self.gaussians,
                    self.color,
                    v.camera.to(self.device, torch.float32),
                    self.background,
                    self._raster,
                    geo,
                )
                scores.append(self._evaluator.score(out.image, v.image, v.mask, key=v.name))
                coverage.append(float(out.alpha.mean()))
        self.view_coverage = dict(zip([v.name for v in views], coverage, strict=True))
        return self._evaluator.mean(scores)

    def background_psnr(self) -> float | None:
        """Mean held-out PSNR of an image filled with the background: what an empty model
        scores (same protocol as :meth:`evaluate`; None without held-out views)."""
        if not self.scene.test:
            return None
        if self._background_psnr is None:
            values = []
            for v in self.scene.test:
                truth = quantize(v.image)
                flat = quantize(self.background.cpu().view(1, 1, 3).expand_as(v.image))
                if v.mask is not None:
                    value = masked_psnr(flat, truth, v.mask.float().numpy())
                else:
                    value = psnr(flat, truth)
                values.append(min(value, PSNR_CEILING))
            self._background_psnr = sum(values) / len(values)
        return self._background_psnr

    def emptiness_warning(self, psnr_db: float | None) -> str | None:
        """A warning when the last evaluated renders are (nearly) empty or score no better
        than the constant background, else None."""
        empty = sorted(n for n, c in self.view_coverage.items() if c < EMPTY_COVERAGE)
        base = self.background_psnr()
        problems = []
        if empty:
            problems.append(
                f"{len(empty)} of {len(self.view_coverage)} evaluated views render (nearly) "
                f"empty (under {EMPTY_COVERAGE:.0%} of pixels covered: {', '.join(empty[:5])})"
            )
        if psnr_db is not None and base is not None and psnr_db <= base + BACKGROUND_MARGIN_DB:
            problems.append(
                f"held-out PSNR {psnr_db:.2f} dB is no better than a constant background image "
                f"({base:.2f} dB)"
            )
        if not problems:
            return None
        return (
            "; ".join(problems) + ". The model may be empty: check the poses (convention, pose), "
            "the background and the preset"
        )

    def _record(self, final: bool = False) -> bool:
        """Evaluate, append and emit one record; returns True if the callback asked to stop."""
        if self._emit(StateChange("evaluating", self.iteration)):
            return True
        t0 = time.perf_counter()
        m = self.evaluate(None if final else self.config.eval_max_views)
        rec = ProgressRecord(
            iteration=self.iteration,
            elapsed_s=self.elapsed_s,
            train_loss=self._loss_sum / self._loss_count if self._loss_count else None,
            psnr=m["psnr"],
            ssim=m["ssim"],
            lpips=m["lpips"],
            avge=m["avge"],
            n_gaussians=len(self.gaussians),
            eval_s=time.perf_counter() - t0,
            final=final,
        )
        self._loss_sum, self._loss_count = 0.0, 0
        self.records.append(rec.to_dict())
        if self.out_dir is not None and not final:
            # Keep the on-disk series current so a long run can be followed (and a killed one
            # still leaves its curve); the PNG is drawn once, at the end.
            self._write_series(plot=False)
        return self._emit(rec)

    # -- checkpoints -------------------------------------------------------------------------
    def state_dict(self) -> dict[str, Any]:
        """Everything needed to continue the run bit-for-bit on CPU."""
        g = self.gaussians
        return {
            "version": 1,
            "config": self.config.to_dict(),
            "scene_name": self.scene.name,
            "iteration": self.iteration,
            "elapsed_s": self.elapsed_s,
            "extent": self.extent,
            "raster_near": self.raster_near,
            "background": self.background.cpu(),
            "gaussians": {k: v.detach().cpu() for k, v in g.params.items()},
            "grad_accum": g.grad_accum.cpu(),
            "grad_count": g.grad_count.cpu(),
            "max_radii": getattr(self, "_max_radii", None),
            "color": self.color.state_dict(),
            "optimizer": self.optimizer.state_dict(),
            "generator": self.generator.get_state(),
            "view_stack": list(self.view_stack),
            "hard_ema": self.hard_ema,
            "step_ema": dict(self._step_ema),
            "records": list(self.records),
        }

    def _load_state(self, state: dict[str, Any]) -> None:
        dev = self.device
        self.iteration = int(state["iteration"])
        self.elapsed_s = float(state["elapsed_s"])
        self.extent = float(state["extent"])
        self.gaussians = Gaussians({k: v.to(dev) for k, v in state["gaussians"].items()})
        self.gaussians.grad_accum = state["grad_accum"].to(dev)
        self.gaussians.grad_count = state["grad_count"].to(dev)
        if state.get("max_radii") is not None:
            self._max_radii = state["max_radii"]
        self.color = make_color_model(state["color"])
        if isinstance(self.color, NeuralColor):
            self.color.field.to(dev)
        self.optimizer = self._make_optimizer()
        self.optimizer.load_state_dict(state["optimizer"])
        self.generator.set_state(state["generator"])
        self.view_stack = list(state["view_stack"])
        self.hard_ema = state["hard_ema"]
        self._step_ema = dict(state.get("step_ema", {}))
        self.records = list(state["records"])

    def save_checkpoint(self, path: str | Path | None = None) -> Path:
        """Write the native checkpoint (default ``out_dir/checkpoint.pt``)."""
        if path is None:
            if self.out_dir is None:
                raise EngineError("save_checkpoint: no path given and the trainer has no out_dir")
            path = self.out_dir / CHECKPOINT_NAME
        return save_checkpoint(self.state_dict(), path)

    # -- the loop ----------------------------------------------------------------------------
    def _tick(self, key: str, t0: float) -> float:
        if self.config.profile:
            t1 = time.perf_counter()
            self.timings[key] = self.timings.get(key, 0.0) + (t1 - t0)
            return t1
        return t0

    def _check_finite(self, value: Tensor, what: str) -> None:
        if not bool(torch.isfinite(value).all()):
            raise TrainingDiverged(
                f"training diverged at step {self.iteration}: {what} is not finite "
                f"(try lower learning rates; lr_means_init={self.config.lr_means_init})"
            )

    def _check_groups(self, grads: bool) -> None:
        """Non-finite values or blown-up magnitudes in any parameter group → TrainingDiverged."""
        for group in self.optimizer.param_groups:
            for p in group["params"]:
                t = p.grad if grads else p
                if t is None:
                    continue
                if not bool(torch.isfinite(t).all()):
                    kind = "gradient" if grads else "value"
                    raise TrainingDiverged(
                        f"training diverged at step {self.iteration}: parameter group "
                        f"{group['name']!r} has a non-finite {kind} (lr={group['lr']:.3g})"
                    )
        if grads:
            return
        # Magnitude guard: a Gaussian 1e3 x the scene extent wide or a centre 1e4 x the extent
        # away is not a scene any more, it is a run blowing up (finite but useless).
        g, lim = self.gaussians, self.extent
        lo, hi = self.box
        scene_size = max(lim, float((hi - lo).max()))
        checks = {
            "log_scales": float(g.log_scales.detach().max()) > math.log(1e3 * scene_size)
            if len(g)
            else False,
            "means": float(g.means.detach().abs().max()) > 1e4 * scene_size + float(hi.abs().max())
            if len(g)
            else False,
        }
        for name, bad in checks.items():
            if bad:
                lr = next(gr["lr"] for gr in self.optimizer.param_groups if gr["name"] == name)
                raise TrainingDiverged(
                    f"training diverged at step {self.iteration}: parameter group {name!r} "
                    f"blew up (values beyond 1e3-1e4 x the scene size; lr={lr:.3g})"
                )

    def _check_step_sizes(self, before: dict[str, Tensor]) -> None:
        """Track the running mean |update| per watched group; raise when one blows up."""
        g, limits = self.gaussians, self.config.divergence_step_limits
        for name, old in before.items():
            new = g.params[name].detach()
            if new.shape != old.shape or new.numel() == 0:
                continue  # densified this step: rows changed, nothing comparable
            d = float((new - old).abs().mean())
            if name == "means":
                d /= self.extent
            ema = self._step_ema.get(name)
            ema = d if ema is None else 0.8 * ema + 0.2 * d
            self._step_ema[name] = ema
            if self.iteration >= 10 and ema > limits[name]:
                lr = next(gr["lr"] for gr in self.optimizer.param_groups if gr["name"] == name)
                unit = " x scene extent" if name == "means" else ""
                raise TrainingDiverged(
                    f"training diverged at step {self.iteration}: parameter group {name!r} "
                    f"moves {ema:.3g}{unit} per step on average (limit {limits[name]}); its "
                    f"learning rate ({lr:.3g}) is too high"
                )

    def _next_view(self) -> int:
        if not self.view_stack:
            self.view_stack = torch.randperm(len(self.cameras), generator=self.generator).tolist()
        return self.view_stack.pop()

    def _depth_loss(self, depth: Tensor, i: int) -> Tensor:
        cfg = self.config
        assert self.priors is not None and self.smooth_guides is not None
        d = depth.reshape(depth.shape[-2], depth.shape[-1])
        loss = global_local_depth_loss(
            d,
            self.priors[i],
            (cfg.patch_min, cfg.patch_max),
            cfg.error_tolerance,
            self.generator,
            cfg.depth_global_weight,
            cfg.depth_local_weight,
        )
        if cfg.depth_smooth_weight > 0 and self.iteration > cfg.depth_smooth_start:
            smooth = edge_aware_smoothness(d / self.extent, self.smooth_guides[i])
            loss = loss + cfg.depth_smooth_weight * smooth
        return loss

    def _clean_views(self) -> None:
        """Prune Gaussians not visible (radius 0) from every training camera."""
        g = self.gaussians
        visible = torch.zeros(len(g), dtype=torch.bool, device=self.device)
        empty = g.means.new_zeros(len(g), 0)
        with torch.no_grad():
            for cam in self.cameras:
                out = self._raster(
                    g.means, g.log_scales, g.quats, g.opacity_logits, empty, cam, None
                )
                visible |= out.radii > 0
        if not bool(visible.all()):
            g.prune(visible, self.optimizer)
            if hasattr(self, "_max_radii"):
                self._max_radii = self._max_radii[visible.cpu()]

    def _step(self) -> None:
        """One training iteration (self.iteration is the 1-based index of this iteration)."""
        cfg, g, it = self.config, self.gaussians, self.iteration
        t = time.perf_counter()
        for group in self.optimizer.param_groups:
            if group["name"] == "means":
                group["lr"] = position_lr(
                    it,
                    cfg.lr_means_init,
                    cfg.lr_means_final,
                    cfg.lr_means_start,
                    cfg.lr_means_steps,
                    self.extent,
                )
        self.color.step_hook(it)
        clean = it in cfg.clean_iterations
        if clean:
            self._clean_views()
            g = self.gaussians
            if len(g) == 0:
                raise ModelCollapsed(f"step {it}: no Gaussian is visible from any training view")
        i = self._next_view()
        cam, gt = self.cameras[i], self.images[i]
        n = len(g)
        empty = g.means.new_zeros(n, 0)
        depth_now = (
            cfg.uses_depth
            and it % cfg.depth_every == 0
            and (cfg.depth_until is None or it < cfg.depth_until)
        )
        t = self._tick("setup", t)
        if depth_now and cfg.hard_depth and it > cfg.hard_depth_start:
            hard = torch.full(
                (n,), float(inverse_sigmoid(torch.tensor(cfg.hard_opacity))), device=self.device
            )
            out = self._raster(
                g.means, g.log_scales.detach(), g.quats.detach(), hard, empty, cam, None
            )
            loss = self._depth_loss(out.depth, i)
            self._check_finite(loss.detach(), "the hard-depth loss")
            loss.backward()
            self.optimizer.step()
            self.optimizer.zero_grad(set_to_none=True)
            hv = float(loss.detach())
            self.hard_ema = hv if self.hard_ema is None else 0.9 * self.hard_ema + 0.1 * hv
            t = self._tick("hard_depth", t)
        soft_gate = cfg.soft_depth_ema_gate is None or (
            self.hard_ema is not None and self.hard_ema < cfg.soft_depth_ema_gate
        )
        if depth_now and cfg.soft_depth and it > cfg.soft_depth_start and soft_gate:
            out = self._raster(
                g.means.detach(),
                g.log_scales.detach(),
                g.quats.detach(),
                g.opacity_logits,
                empty,
                cam,
                None,
            )
            loss = self._depth_loss(out.depth, i)
            self._check_finite(loss.detach(), "the soft-depth loss")
            loss.backward()
            self.optimizer.step()
            self.optimizer.zero_grad(set_to_none=True)
            t = self._tick("soft_depth", t)

        # Photometric pass.
        colors = self.color.colors(g, cam.center)
        t = self._tick("neural_fwd", t)
        leaf = colors.detach().requires_grad_(True) if cfg.profile else colors
        out = self._raster(
            g.means, g.log_scales, g.quats, g.opacity_logits, leaf, cam, self.background
        )
        t = self._tick("photo_render", t)
        scales = g.scales
        photo = photometric_loss(out.image, gt, cfg.lambda_dssim, self.ssim_targets[i])
        loss = photo
        if cfg.shape_weight:
            loss = loss + cfg.shape_weight * shape_regularizer(scales)
        if cfg.scale_weight:
            loss = loss + cfg.scale_weight * scale_regularizer(scales / self.extent)
        if cfg.opacity_weight:
            loss = loss + cfg.opacity_weight * opacity_regularizer(g.opacity)
        self._check_finite(loss.detach(), "the photometric loss")
        t = self._tick("losses", t)
        loss.backward()
        t = self._tick("photo_backward", t)
        if cfg.profile and leaf.grad is not None:
            colors.backward(leaf.grad)
            t = self._tick("neural_bwd", t)
        self._loss_sum += float(photo.detach())
        self._loss_count += 1

        if it < cfg.densify_until and not clean:
            grad = out.means2d.grad
            if grad is not None:
                w, h = cam.width, cam.height
                # Our means2d are pixels; the reference thresholds are in the 3DGS rasterizer's
                # NDC-gradient units: d/dndc = d/dpix * (size / 2).
                ndc = grad * torch.tensor([0.5 * w, 0.5 * h], device=grad.device)
                g.add_densification_stats(ndc, out.radii > 0)
            if cfg.max_screen_size is not None:
                r = out.radii.detach().float().cpu()
                prev = getattr(self, "_max_radii", torch.zeros(len(g)))
                self._max_radii = torch.maximum(prev, r) if prev.shape == r.shape else r
        if it < cfg.densify_until and it > cfg.densify_from and it % cfg.densify_interval == 0:
            reset_done = cfg.opacity_reset_interval is not None and it > cfg.opacity_reset_interval
            g.densify_and_prune(
                self.optimizer,
                grad_threshold=cfg.densify_grad_threshold,
                percent_dense=cfg.percent_dense,
                scene_extent=self.extent,
                min_opacity=cfg.prune_opacity,
                split_opacity_threshold=cfg.split_opacity_threshold,
                generator=self.generator,
                max_screen_radius=getattr(self, "_max_radii", None) if reset_done else None,
                max_screen_size=cfg.max_screen_size if reset_done else None,
                max_world_size=cfg.max_world_size * self.extent if cfg.max_world_size else None,
                max_gaussians=cfg.max_gaussians,
            )
            self._max_radii = torch.zeros(len(g))
            if len(g) == 0:
                raise ModelCollapsed(
                    f"step {it}: every Gaussian was pruned (prune_opacity={cfg.prune_opacity})"
                )
            t = self._tick("densify", t)
        if (
            cfg.opacity_reset_interval
            and it % cfg.opacity_reset_interval == 0
            and it < cfg.densify_until
        ):
            g.reset_opacity(self.optimizer)
        if it % cfg.divergence_check_every == 0:
            self._check_groups(grads=True)
        watched = {
            k: v.detach().clone() for k, v in g.params.items() if k in cfg.divergence_step_limits
        }
        self.optimizer.step()
        self.optimizer.zero_grad(set_to_none=True)
        self._check_step_sizes(watched)
        if it % cfg.divergence_check_every == 0 or it == cfg.iterations:
            self._check_groups(grads=False)
        self._tick("optimizer", t)

    def run(self) -> TrainResult:
        """Train to ``config.iterations`` (or until the callback says stop); evaluate, save."""
        cfg = self.config
        prev_threads = torch.get_num_threads()
        if cfg.threads:
            torch.set_num_threads(cfg.threads)
        try:
            return self._run()
        except (TrainingDiverged, ModelCollapsed) as exc:
            self._emit(StateChange("failed", self.iteration, str(exc)))
            raise
        finally:
            torch.set_num_threads(prev_threads)

    def _run(self) -> TrainResult:
        cfg = self.config
        self._emit(StateChange("initializing", self.iteration))
        if self.iteration == 0 and self._record():
            return self._finish(stopped=True)
        self._emit(StateChange("training", self.iteration))
        since_eval = since_ckpt = 0.0
        while self.iteration < cfg.iterations:
            t0 = time.perf_counter()
            self.iteration += 1
            self._step()
            dt = time.perf_counter() - t0
            self.elapsed_s += dt
            since_eval += dt
            since_ckpt += dt
            if self.stop_requested:
                return self._finish(stopped=True)
            if self.iteration == cfg.iterations:
                break
            due = (cfg.eval_interval_s > 0 and since_eval >= cfg.eval_interval_s) or (
                cfg.eval_every is not None and self.iteration % cfg.eval_every == 0
            )
            if due:
                since_eval = 0.0
                if self._record():
                    return self._finish(stopped=True)
                self._emit(StateChange("training", self.iteration))
            if cfg.checkpoint_interval_s > 0 and since_ckpt >= cfg.checkpoint_interval_s:
                since_ckpt = 0.0
                if self.out_dir is not None:
                    self._emit(StateChange("checkpointing", self.iteration))
                    self.save_checkpoint()
        if self.iteration in cfg.clean_iterations:
            self._clean_views()
        self._record(final=True)
        return self._finish(stopped=False)

    def _finish(self, stopped: bool) -> TrainResult:
        artifacts: dict[str, Path] = {}
        last = self.records[-1] if self.records else {}
        metrics: dict[str, Any] = {k: last.get(k) for k in ("psnr", "ssim", "lpips", "avge")}
        metrics.update(
            seconds=self.elapsed_s,
            iterations=self.iteration,
            n_gaussians=len(self.gaussians),
            preset=self.config.preset,
            stopped=stopped,
            background_psnr=self.background_psnr(),
        )
        if not self.scene.test:  # no held-out views: judge emptiness on the training views
            with torch.no_grad():
                self.view_coverage = {
                    v.name: float(self.render(v.camera).alpha.mean()) for v in self.scene.train
                }
        if self.view_coverage:
            metrics["coverage"] = sum(self.view_coverage.values()) / len(self.view_coverage)
        warning = self.emptiness_warning(metrics.get("psnr"))
        if warning:  # surfaced by the caller (the CLI prints it, the service stores it)
            log.info("%s: %s", self.scene.name, warning)
            metrics["warnings"] = [warning]
        if self.out_dir is not None:
            self.out_dir.mkdir(parents=True, exist_ok=True)
            self._emit(StateChange("checkpointing", self.iteration))
            artifacts["checkpoint"] = self.save_checkpoint()
            if not stopped and self.config.export:
                artifacts.update(self._export(metrics))
            artifacts.update(self._write_series())
            metrics["series"] = self.records
            path = self.out_dir / "metrics.json"
            # Valid JSON: no bare Infinity/NaN (non-finite figures are written as null).
            path.write_text(json.dumps(json_safe(metrics), indent=1, default=str, allow_nan=False))
            artifacts["metrics"] = path
            del metrics["series"]
        self._emit(StateChange("stopped" if stopped else "finished", self.iteration))
        return TrainResult(
            metrics=metrics,
            artifacts=artifacts,
            seconds=self.elapsed_s,
            n_gaussians=len(self.gaussians),
            records=list(self.records),
            stopped=stopped,
            iteration=self.iteration,
        )

    def _write_series(self, plot: bool = True) -> dict[str, Path]:
        try:
            from sparsesplat.engine.report import write_report
        except ImportError:
            return {}
        assert self.out_dir is not None
        paths = write_report(self.records, self.out_dir, plot=plot)
        return {f"series_{k}": Path(v) for k, v in paths.items()}

    def _export(self, metrics: dict[str, Any]) -> dict[str, Path]:
        """.ply and .splat; neural colours are baked into degree-3 SH first."""
        try:
            from sparsesplat.engine.export import export_ply, export_splat
        except ImportError:
            return {}
        assert self.out_dir is not None
        sh = model_sh(self.gaussians, self.color, [c for c in self.cameras])
        g = self.gaussians
        args = (
            g.means.detach().cpu(),
            g.log_scales.detach().cpu(),
            g.quats.detach().cpu(),
            g.opacity_logits.detach().cpu(),
            sh,
        )
        out = {"ply": self.out_dir / "model.ply", "splat": self.out_dir / "model.splat"}
        export_ply(out["ply"], *args)
        export_splat(out["splat"], *args)
        if isinstance(self.color, NeuralColor):
            baking = _baking_psnr(g, self.color, sh, self.cameras, self.background)
            # Identical renders give +inf: kept at the held-out PSNR ceiling (valid JSON).
            metrics["sh_baking_psnr"] = None if baking is None else min(baking, PSNR_CEILING)
        return out


def model_sh(gaussians: Gaussians, color: ColorModel, cameras: list[Camera]) -> Tensor:
    """(N, K, 3) SH coefficients of the model: exact for SH colour, baked (degree 3, least
    squares over sphere samples plus the training directions) for neural colour."""
    if isinstance(color, SHColor):
        dc = gaussians.params["sh_dc"].detach().cpu()
        if "sh_rest" in gaussians.params:
            return torch.cat([dc, gaussians.params["sh_rest"].detach().cpu()], dim=1)
        return dc
    from sparsesplat.engine.export import bake_sh

    means = gaussians.means.detach()
    centers = torch.stack([c.center.to(means) for c in cameras])
    view_dirs = torch.nn.functional.normalize(means[:, None, :] - centers[None], dim=-1)
    return bake_sh(
        color.color_fn(gaussians),
        len(gaussians),
        degree=3,
        view_dirs=view_dirs.cpu(),
        device=means.device,
    )


def _baking_psnr(
    g: Gaussians, color: NeuralColor, sh: Tensor, cameras: list[Camera], background: Tensor
) -> float | None:
    try:
        from sparsesplat.engine.export import sh_baking_error
    except ImportError:
        return None
    geo = color.geo_features(g)
    means = g.means.detach()

    def neural(cam: Camera) -> Tensor:
        return color.colors_cached(geo, means, cam.center.to(means)).cpu()

    return float(
        sh_baking_error(
            means.cpu(),
            g.log_scales.detach().cpu(),
            g.quats.detach().cpu(),
            g.opacity_logits.detach().cpu(),
            sh,
            neural,
            [c.to("cpu") for c in cameras],
            background.cpu(),
        )
    )


def _render_model(
    g: Gaussians,
    color: ColorModel,
    cam: Camera,
    background: Tensor,
    raster: Callable[..., RasterOutput],
    geo: Tensor | None,
) -> RasterOutput:
    """Render with cached geometry features when given (inference path)."""
    with torch.no_grad():
        if isinstance(color, NeuralColor):
            geo = geo if geo is not None else color.geo_features(g)
            feats = color.colors_cached(geo, g.means, cam.center.to(g.means))
        else:
            feats = color.colors(g, cam.center.to(g.means))
        return raster(
            g.means, g.log_scales, g.quats, g.opacity_logits, feats, cam, background.to(g.means)
        )
