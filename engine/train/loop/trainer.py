"""The DNGaussian trainer: sparse-view 3DGS with hard/soft depth and Global-Local normalization.

One iteration follows the reference code (dngaussian-method.md §1.6): up to three separate
forward/backward passes, each followed by its own step of ONE shared Adam optimizer
(``zero_grad(set_to_none=True)`` in between, so a pass only moves the tensors it reaches):

1. hard depth: opacity 0.95 everywhere, scales/rotations detached → only centres move;
2. soft depth (after ``soft_depth_start``): centres/scales/rotations detached → only opacities;
3. photometric: L1 + λ·D-SSIM + shape/scale/opacity regularizers → everything; densification.

``auxiliary_step='joint'`` instead keeps the depth passes' gradients for the photometric step
(the paper's single objective, one optimizer step per iteration).

The loop below reads as the method does; each concern is a part with its own settings and
state (``parts.py`` says what a part is). In this folder:

- :class:`DensifyStrategy` (``densify.py``): clean-views pruning, clone/split/prune, reset;
- :class:`DivergenceGuard` (``guard.py``): finite, magnitude and step-size checks;
- :class:`Recorder` (``recorder.py``): evaluation, the error-vs-time series, exports (through
  the model package, ``engine/model/``);
- the run's data on its device, prepared once (``data.py``): targets, cameras, box, extent;
- the optimizer and its LR schedule (``optimizer.py``, ``schedule.py``), the checkpoint state
  (``state.py``), the result (``result.py``).

In ``engine/train/regularizers/``: :class:`DepthRegularizer` (passes 1 and 2, built when the
config uses depth) and the optional parts, each built only when its switch is on (dropout, DTU
background, warp and binocular consistency, correspondence, near-plane pruning; ``parts.py``
lists their hooks). The initial Gaussians come from ``engine/train/init/``.

Deviations from the reference, on purpose: guarded depth loss (empty selection, zero variance),
no unused SH tensors, geometry features cached per evaluation, a fixed hash-grid resolution
(scale-free), an optional cap on the number of Gaussians, no Blender scene-name hacks.

No global state: each trainer owns its torch.Generator, optimizer and models.
"""

from __future__ import annotations

import functools
import time
from collections.abc import Callable
from contextlib import nullcontext
from pathlib import Path
from typing import Any

import torch
from torch import Tensor

from sparsesplat.engine.camera import Camera
from sparsesplat.engine.color.build import release_cached_memory
from sparsesplat.engine.color.models import ColorModel
from sparsesplat.engine.denormals import flush_denormals
from sparsesplat.engine.errors import EngineError, SceneError, TrainingDiverged
from sparsesplat.engine.losses import (
    opacity_regularizer,
    photometric_loss,
    scale_regularizer,
    shape_regularizer,
)
from sparsesplat.engine.malloc import keep_freed_memory
from sparsesplat.engine.model.checkpoint import (
    CHECKPOINT_NAME,
    CheckpointError,
    load_checkpoint,
    save_checkpoint,
)
from sparsesplat.engine.model.render import render_view, view_colors
from sparsesplat.engine.raster import RasterOutput
from sparsesplat.engine.scene import Scene
from sparsesplat.engine.threads import torch_threads
from sparsesplat.engine.train.config import TrainConfig
from sparsesplat.engine.train.init.initial_points import initial_points, with_matched
from sparsesplat.engine.train.init.matched_points import RunMatches, run_matches
from sparsesplat.engine.train.init.model import initial_model
from sparsesplat.engine.train.loop.data import run_data
from sparsesplat.engine.train.loop.densify import DensifyStrategy, ModelCollapsed
from sparsesplat.engine.train.loop.guard import DivergenceGuard
from sparsesplat.engine.train.loop.optimizer import make_optimizer, set_position_lr
from sparsesplat.engine.train.loop.parts import AuxiliaryStep, StageTimer, TrainView
from sparsesplat.engine.train.loop.poses import PoseRefinement
from sparsesplat.engine.train.loop.progress import (
    ProgressCallback,
    ProgressRecord,
    StateChange,
    wants_stop,
)
from sparsesplat.engine.train.loop.recorder import Recorder, json_safe
from sparsesplat.engine.train.loop.result import TrainResult, note_time
from sparsesplat.engine.train.loop.schedule import ScheduleClock
from sparsesplat.engine.train.loop.state import restore_trainer, trainer_state
from sparsesplat.engine.train.regularizers.binocular import BinocularConsistency
from sparsesplat.engine.train.regularizers.consistency import WarpConsistency
from sparsesplat.engine.train.regularizers.correspondence import CorrespondenceTerm
from sparsesplat.engine.train.regularizers.depth_gate import agreeing_views
from sparsesplat.engine.train.regularizers.depth_regularizer import DepthRegularizer, hard_downscale
from sparsesplat.engine.train.regularizers.dropout import PhotometricDropout, scatter_output
from sparsesplat.engine.train.regularizers.dtu_background import DtuBackground
from sparsesplat.engine.train.regularizers.near_prune import NearPrune
from sparsesplat.engine.train.regularizers.pseudo_views import PseudoViewDepth, monocular_network


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
        init_depth: list[Any] | None = None,
        time_source: Callable[[], float] = time.perf_counter,
    ) -> None:
        """Set up the model. ``priors``: one PriorDepth (or (H, W) tensor) per training view, or
        None when the config uses no depth. ``resume_from``: a checkpoint to continue.
        ``init_depth``: metric PriorDepths for ``init.method='dense'``; None uses ``priors``
        when they are metric, else computes a plane-sweep prior (cached under
        ``out_dir/priors``). ``time_source``: the clock training seconds are measured with
        (tests inject a fake one to drive a time budget)."""
        self.config = config.validate()
        self.time_source = time_source
        self.clock = ScheduleClock(config.iterations, config.time_budget_s, config.time_limit_s)
        """The schedule position the parts compare their schedule fields with."""
        self.scene = scene
        self.device = torch.device(device)
        self.out_dir = Path(out_dir) if out_dir is not None else None
        self.on_progress = on_progress
        if not scene.train:
            raise SceneError(f"scene {scene.name!r}: no training views")
        self.generator = torch.Generator().manual_seed(config.seed)
        self._setup_data()
        self.depth: DepthRegularizer | None = None
        """The depth regulariser; None when the config uses no depth (or the agreement gate
        left no view with its prior)."""
        self.depth_agreement: list[float] | None = None
        """Per training view, the prior's Spearman agreement with a plane sweep (only when
        ``depth_min_agreement`` is set)."""
        if self.config.uses_depth:
            views = self._depth_views(priors)
            if views is None or views:
                self.depth = DepthRegularizer(
                    self.config.depth,
                    priors,
                    self.images,
                    self.background,
                    [v.name for v in self.scene.train],
                    self._raster,
                    self.generator,
                    self.clock,
                    views,
                    joint=self.config.optim.joint,
                    fill_background=self.config.dtu.enabled and self.config.dtu.depth_fill,
                    hard_downscale=hard_downscale(self.config.depth, self.cameras),
                )
        self.init_note: str | None = None
        """How the initial Gaussians were made when ``init='dense'`` (also in the metrics)."""
        self.matches: RunMatches | None = None
        """The training photos' matched, triangulated points; None unless the init or the
        correspondence term uses them (``TrainConfig.uses_matches``)."""
        if self.config.uses_matches:
            cache = self.out_dir / "priors" if self.out_dir is not None else None
            photos = [v.image for v in self.scene.train]
            with torch_threads(self.config.threads):  # the run's count, as for its iterations
                self.matches = run_matches(self.config.matches, photos, self.cameras, cache)
        self._setup_model(init_depth if init_depth is not None else priors)
        cfg, clock = self.config, self.clock
        self.densify: DensifyStrategy | None = None
        """The densification strategy; None when the run never densifies nor cleans."""
        if cfg.densify.active:
            self.densify = DensifyStrategy(
                cfg.densify, self.cameras, self._raster, self.generator, clock
            )
        self.dropout: PhotometricDropout | None = None
        """DropGaussian on the photometric pass; None unless ``dropout.enabled``."""
        if cfg.dropout.enabled:
            self.dropout = PhotometricDropout(cfg.dropout, self.generator, clock)
        self.dtu: DtuBackground | None = None
        """DTU black-background handling; None unless ``dtu.enabled``."""
        if cfg.dtu.enabled:
            self.dtu = DtuBackground(
                cfg.dtu, self.scene.name, self.images, self._raster, cfg.optim.joint
            )
        self.consistency: WarpConsistency | None = None
        """The warp-consistency term; None unless ``consistency.weight > 0``."""
        if cfg.consistency.enabled:
            self.consistency = WarpConsistency(
                cfg.consistency, self.cameras, self.images, self._raster, clock
            )
        self.binocular: BinocularConsistency | None = None
        """Binocular self-consistency; None unless ``binocular.weight > 0``."""
        if cfg.binocular.enabled:
            self.binocular = BinocularConsistency(
                cfg.binocular, self.extent, self._raster, self.generator, clock
            )
        self.pseudo: PseudoViewDepth | None = None
        """Depth at pseudo views; None unless ``pseudo.weight > 0`` and the run's prior is a
        monocular network."""
        if cfg.pseudo.enabled:
            network, network_file = monocular_network(cfg.depth)
            self.pseudo = PseudoViewDepth(
                cfg.pseudo, cfg.depth, self.cameras, self._raster, self.generator, clock,
                network, network_file, self.background, hard_downscale(cfg.depth, self.cameras),
                self.extent, cfg.optim.joint,
            )  # fmt: skip
        self.correspondence: CorrespondenceTerm | None = None
        """The matched-depth term; None unless ``correspondence.weight > 0`` and the run has
        matched points."""
        if cfg.correspondence.enabled and self.matches is not None and not self.matches.empty:
            self.correspondence = CorrespondenceTerm(
                cfg.correspondence, self.matches, self.cameras, clock
            )
        self.poses: PoseRefinement | None = None
        """The training cameras' refinement; None unless ``poses.enabled``."""
        if cfg.poses.enabled and len(self.cameras) > 1:
            self.poses = PoseRefinement(cfg.poses, self.cameras, self.extent, clock)
        self.near_prune: NearPrune | None = None
        """Near-plane pruning; None unless ``near_prune.enabled``."""
        if cfg.near_prune.enabled:
            self.near_prune = NearPrune(cfg.near_prune, self.scene, clock)
        self.guard = DivergenceGuard(cfg.guard, self.box, cfg.iterations, cfg.optim.lr_means_init)
        self.recorder = Recorder(
            cfg.record, self.scene, self.background, self._raster, self.out_dir, cfg.preset
        )
        if self.near_prune is not None:
            self.recorder.eval_keep = self.near_prune.eval_keep
        self.timer = StageTimer(self.config.record.profile)
        self.iteration = 0
        # Matching is part of training: the run's clock (its time limit, the error-against-time
        # record) starts with the seconds it took.
        self.elapsed_s = self.matches.seconds if self.matches is not None else 0.0
        # ... but not to the pace the schedule keeps under a time limit: a run fast enough
        # for its limit trains the plain schedule from its first iteration.
        self.clock.setup_s = self.elapsed_s
        self.view_stack: list[int] = []
        self.stop_requested = False
        """Set from another thread (a job's cancel or a time budget): the run stops after the
        current iteration, with a checkpoint, as if the progress callback had said stop."""
        self.discard_outputs = False
        """Set from another thread, with ``stop_requested``, when the run's files are no longer
        its own to write (the job was deleted, or its lease passed to another worker): no
        checkpoint or export is written from then on."""
        if resume_from is not None:
            state = load_checkpoint(resume_from)
            if state.get("model_only"):
                raise CheckpointError(
                    f"checkpoint {resume_from}: a finished model (no optimizer state); it "
                    "renders and exports, but training cannot resume from it"
                )
            restore_trainer(self, state)

    # -- setup -----------------------------------------------------------------------------
    def _setup_data(self) -> None:
        data = run_data(self.scene, self.config, self.device)
        self.scene, self.background = data.scene, data.background
        self.cameras, self.images, self.ssim_targets = data.cameras, data.images, data.ssim_targets
        self.box, self.extent, self.raster_near = data.box, data.extent, data.raster_near
        self._raster = data.raster
        """The run's rasterizer (the parts, the evaluation and :meth:`render` share it)."""

    def _depth_views(self, priors: list[Any] | None) -> set[int] | None:
        """The training views whose prior the depth passes use (None: all of them)."""
        threshold = self.config.depth.min_agreement
        if threshold is None or priors is None or len(priors) != len(self.scene.train):
            return None  # (a missing or misaligned prior is reported by the regulariser)
        cache = self.out_dir / "priors" if self.out_dir is not None else None
        views, self.depth_agreement = agreeing_views(self.scene, priors, threshold, cache)
        return views

    def _initial_points(self, depth: list[Any] | None) -> tuple[Tensor, Tensor | None]:
        """Hook ``init_points``: points (N, 3) and, from the dense/sparse inits, colours."""
        cache = self.out_dir / "priors" if self.out_dir is not None else None
        start = initial_points(
            self.config.init, self.scene, self.box, self.cameras, depth, cache, self.generator
        )
        points, colours, note = with_matched(self.config.init, start, self.matches)
        self.init_note = note if note is not None else self.init_note
        return points, colours

    def _setup_model(self, init_depth: list[Any] | None) -> None:
        points, colours = self._initial_points(init_depth)
        self.color: ColorModel
        self.gaussians, self.color = initial_model(
            self.config, points, colours, self.generator, self.device
        )
        self.optimizer = make_optimizer(self.config.optim, self.gaussians, self.color, self.extent)

    # -- views of the parts (public surface used by the CLI, the service and benchmarks) --------
    @property
    def priors(self) -> list[Tensor] | None:
        """The prepared depth priors (None without depth)."""
        return self.depth.priors if self.depth is not None else None

    @property
    def hard_ema(self) -> float | None:
        """Running mean of the hard-depth loss (None without depth or before its first step)."""
        return self.depth.hard_ema if self.depth is not None else None

    @property
    def records(self) -> list[dict[str, Any]]:
        """The error-vs-time series so far."""
        return self.recorder.records

    @property
    def timings(self) -> dict[str, float]:
        """Accumulated seconds per stage when ``config.profile`` is on."""
        return self.timer.totals

    @property
    def view_coverage(self) -> dict[str, float]:
        """Mean alpha of each view's render at the last evaluation (by view name)."""
        return self.recorder.view_coverage

    @view_coverage.setter
    def view_coverage(self, value: dict[str, float]) -> None:
        self.recorder.view_coverage = value

    def background_psnr(self) -> float | None:
        """Held-out PSNR of the constant background image (see :class:`Recorder`)."""
        return self.recorder.background_psnr()

    def emptiness_warning(self, psnr_db: float | None) -> str | None:
        """A warning when the model looks empty (see :class:`Recorder`)."""
        return self.recorder.emptiness_warning(psnr_db)

    def evaluate(self, max_views: int | None = None) -> dict[str, float | None]:
        """Mean held-out metrics (all None when the scene has no held-out views)."""
        return self.recorder.evaluate(self.gaussians, self.color, max_views)

    def training_cameras(self) -> list[Camera]:
        """The training cameras as trained: refined when ``poses.enabled``."""
        return self.cameras if self.poses is None else self.poses.refined()

    # -- rendering ---------------------------------------------------------------------------
    def render(self, camera: Camera, background: Tensor | None = None) -> RasterOutput:
        """Render the current model through ``camera`` without gradients."""
        return render_view(
            self.gaussians,
            view_colors(self.color, self.gaussians),
            camera.to(self.device, torch.float32),
            self.background if background is None else background,
            self._raster,
        )

    # -- progress ----------------------------------------------------------------------------
    def _emit(self, event: ProgressRecord | StateChange) -> bool:
        if self.on_progress is None:
            return False
        return wants_stop(self.on_progress(event))

    def _record(self, final: bool = False) -> bool:
        """Evaluate, append and emit one record; returns True if the callback asked to stop."""
        if self._emit(StateChange("evaluating", self.iteration)):
            return True
        records = self.recorder.record(
            self.iteration, self.elapsed_s, self.gaussians, self.color, final
        )
        stop = False
        for rec in records:
            stop = self._emit(rec) or stop
        return stop

    # -- checkpoints -------------------------------------------------------------------------
    def state_dict(self) -> dict[str, Any]:
        """Everything needed to continue the run bit-for-bit on CPU (``state.py``)."""
        return trainer_state(self)

    def save_checkpoint(self, path: str | Path | None = None) -> Path:
        """Write the native checkpoint (default ``out_dir/checkpoint.pt``)."""
        if path is None:
            if self.out_dir is None:
                raise EngineError("save_checkpoint: no path given and the trainer has no out_dir")
            path = self.out_dir / CHECKPOINT_NAME
        return save_checkpoint(self.state_dict(), path)

    # -- the loop ----------------------------------------------------------------------------
    def _next_view(self) -> TrainView:
        if not self.view_stack:
            self.view_stack = torch.randperm(len(self.cameras), generator=self.generator).tolist()
        i = self.view_stack.pop()
        camera = self.cameras[i] if self.poses is None else self.poses.camera(i)
        return TrainView(i, camera, self.images[i], self.ssim_targets[i])

    def _photometric_loss(self, image: Tensor, view: TrainView) -> tuple[Tensor, Tensor]:
        """(total, photometric): L1 + λ·D-SSIM plus DNGaussian's shape/scale/opacity terms."""
        cfg, g = self.config.photometric, self.gaussians
        scales = g.scales
        photo = photometric_loss(image, view.image, cfg.lambda_dssim, view.ssim_target)
        loss = photo
        if cfg.shape_weight:
            loss = loss + cfg.shape_weight * shape_regularizer(scales)
        if cfg.scale_weight:
            loss = loss + cfg.scale_weight * scale_regularizer(scales / self.extent)
        if cfg.opacity_weight:
            loss = loss + cfg.opacity_weight * opacity_regularizer(g.opacity)
        return loss, photo

    def _step(self) -> None:
        """One training iteration (self.iteration is the 1-based index of this iteration)."""
        cfg, it, timer, opt = self.config, self.iteration, self.timer, self.optimizer
        timer.start()
        # The decay follows the schedule position (the iteration itself without a budget).
        set_position_lr(opt, cfg.optim, self.clock.position(it), self.extent)
        self.color.step_hook(self.clock.position(it), self.clock.previous(it))
        cleaned = False
        if self.densify is not None:
            cleaned = self.densify.step_pre_backward(it, self.gaussians, opt)
        g = self.gaussians
        view = self._next_view()
        if self.dtu is not None:
            view = self.dtu.adjust_view(view)
        timer.tick("setup")

        # Passes 1 and 2: hard and soft depth, each with its own optimizer step.
        aux = AuxiliaryStep(it, g, opt, view, self.extent, self.guard, timer)
        if self.depth is not None:
            self.depth.step_pre_photometric(aux)
        if self.dtu is not None:  # DTU background alpha, own optimizer step
            self.dtu.step_pre_photometric(aux)
        if self.pseudo is not None:  # depth at a pseudo view, own optimizer step
            self.pseudo.step_pre_photometric(aux, self.color)

        # Pass 3: photometric. Only the Gaussians DropGaussian keeps are coloured and rendered.
        drop = self.dropout.draw(it, len(g), self.device) if self.dropout is not None else None
        colors = self.color.colors(g, view.camera.center, None if drop is None else drop.index)
        timer.tick("neural_fwd")
        # Profiling splits the colour field's backward from the rasterizer's.
        leaf = colors.detach().requires_grad_(True) if cfg.record.profile else colors
        inputs: tuple[Tensor, ...]
        if drop is None:
            inputs = (g.means, g.log_scales, g.quats, g.opacity_logits, leaf)
        else:  # only the kept rows are rendered, their opacities compensated
            inputs = (
                drop.select(g.means),
                drop.select(g.log_scales),
                drop.select(g.quats),
                drop.opacity_logits(g.opacity_logits),
                leaf,
            )
        camera = view.camera
        if self.poses is not None:  # the refined camera: the Gaussians moved, the pose as given
            means, quats = self.poses.move(view.index, inputs[0], inputs[2])
            inputs, camera = (means, inputs[1], quats, *inputs[3:]), self.cameras[view.index]
        fused_soft = self.depth is not None and self.depth.wants_fused_soft(it, view)
        out = self._raster(*inputs, camera, self.background, opacity_depth=fused_soft)
        timer.tick("photo_render")
        loss, photo = self._photometric_loss(out.image, view)
        timer.tick("losses")
        if self.consistency is not None:
            extra = self.consistency.extra_loss(it, g, out, view)
            loss = loss if extra is None else loss + extra
            timer.tick("consistency")
        if self.binocular is not None:
            extra = self.binocular.extra_loss(it, inputs, out, camera, view.image, self.background)
            loss = loss if extra is None else loss + extra
            timer.tick("binocular")
        if self.correspondence is not None:
            extra = self.correspondence.extra_loss(it, out, view)
            loss = loss if extra is None else loss + extra
            timer.tick("correspondence")
        if fused_soft and self.depth is not None and out.opacity_depth is not None:
            # DNGaussian's soft-depth term on this render: its gradient reaches the opacities
            # only (the rasterizer routes it), as the reference's detached pass would.
            soft = self.depth.soft_loss(out.opacity_depth, view, it, self.extent)
            self.guard.check_finite(soft.detach(), "the soft-depth loss", it)
            loss = loss + soft
            timer.tick("soft_depth")
        self.guard.check_finite(loss.detach(), "the photometric loss", it)
        timer.tick("losses")
        loss.backward()
        timer.tick("photo_backward")
        if cfg.record.profile and leaf.grad is not None:
            colors.backward(leaf.grad)
            timer.tick("neural_bwd")
        self.recorder.add_train_loss(float(photo.detach()))
        if self.poses is not None:
            self.poses.step(it)
        if drop is not None:
            out = scatter_output(drop, out)

        if self.densify is not None:
            rule = None
            if self.dtu is not None:
                seen = functools.partial(self.color.colors, camera_center=view.camera.center)
                rule = self.dtu.densify_rule(it, seen)
            self.densify.step_post_backward(
                it, g, opt, out, view.camera, cleaned, self.extent, timer, rule
            )
        if self.near_prune is not None:
            self.near_prune.step(it, g, opt)
        before = self.guard.before_step(it, opt, g, self.extent)
        opt.step()
        opt.zero_grad(set_to_none=True)
        self.guard.after_step(it, opt, g, self.extent, before)
        decay = cfg.densify.opacity_decay
        if decay < 1.0 and self.clock.position(it) < cfg.densify.until:
            g.decay_opacity(decay)
        timer.tick("optimizer")

    def run(self) -> TrainResult:
        """Train to ``config.iterations`` (or sooner, at ``config.time_limit_s``), or under
        ``config.time_budget_s`` until the budget is spent (or until the callback says stop);
        evaluate, save."""
        cfg = self.config
        keep_freed_memory()  # reuse the step's large buffers (see engine/malloc.py)
        # After the thread count: the mode is per thread (see engine/denormals.py).
        fp_mode = flush_denormals() if self.device.type == "cpu" else nullcontext()
        try:
            with torch_threads(cfg.threads), fp_mode:
                return self._run()
        except (TrainingDiverged, ModelCollapsed) as exc:
            self._emit(StateChange("failed", self.iteration, str(exc)))
            raise
        finally:
            release_cached_memory()  # the hash grid's gradient block (engine/color/build.py)

    def _run(self) -> TrainResult:
        clock, rec = self.clock, self.config.record
        self._emit(StateChange("initializing", self.iteration))
        if self.iteration == 0 and self._record():
            return self._finish(stopped=True)
        self._emit(StateChange("training", self.iteration))
        since_eval = since_ckpt = 0.0
        while not clock.finished(self.iteration, self.elapsed_s):
            t0 = self.time_source()
            self.iteration += 1
            clock.advance(self.elapsed_s, self.iteration)
            self._step()
            dt = self.time_source() - t0
            self.elapsed_s += dt
            since_eval += dt
            since_ckpt += dt
            if self.stop_requested:
                return self._finish(stopped=True)
            if clock.finished(self.iteration, self.elapsed_s):
                break
            due = (rec.eval_interval_s > 0 and since_eval >= rec.eval_interval_s) or (
                rec.eval_every is not None and self.iteration % rec.eval_every == 0
            )
            if due:
                since_eval = 0.0
                if self._record():
                    return self._finish(stopped=True)
                self._emit(StateChange("training", self.iteration))
            if rec.checkpoint_interval_s > 0 and since_ckpt >= rec.checkpoint_interval_s:
                since_ckpt = 0.0
                if self.out_dir is not None and not self.discard_outputs:
                    self._emit(StateChange("checkpointing", self.iteration))
                    self.save_checkpoint()
        if self.densify is not None:
            self.densify.finish(self.iteration, self.gaussians, self.optimizer)
        self._record(final=True)
        return self._finish(stopped=False)

    def _finish(self, stopped: bool) -> TrainResult:
        artifacts: dict[str, Path] = {}
        metrics = self.recorder.final_metrics(
            self.iteration, self.elapsed_s, self.gaussians, self.color, stopped
        )
        if self.init_note is not None:
            metrics["init"] = self.init_note
        note_time(metrics, self.config, self.clock, self.iteration, self.elapsed_s, stopped)
        if self.matches is not None:
            metrics["matches"] = self.matches.summary
            if "error" in self.matches.summary:  # the run went on without the matched parts
                metrics.setdefault("warnings", []).append(
                    f"matched start and matched-depth term not used: "
                    f"{self.matches.summary['error']}"
                )
        if self.near_prune is not None:
            metrics["near_pruned"] = self.near_prune.pruned
        if self.poses is not None:
            metrics["pose_refinement"] = self.poses.summary()
        if self.depth_agreement is not None:
            metrics["depth_agreement"] = json_safe(self.depth_agreement)
            metrics["depth_views"] = sorted(self.depth.views or []) if self.depth else []
        if self.out_dir is not None and not self.discard_outputs:
            self.out_dir.mkdir(parents=True, exist_ok=True)
            self._emit(StateChange("checkpointing", self.iteration))
            artifacts["checkpoint"] = self.save_checkpoint()
            artifacts.update(
                self.recorder.write_outputs(
                    metrics, self.gaussians, self.color, self.training_cameras(), stopped
                )
            )
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
