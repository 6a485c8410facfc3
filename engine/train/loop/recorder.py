"""Recording and export: held-out evaluation, the error-vs-time series, the emptiness check
(coverage and the constant-background PSNR), and the end-of-run files (the model's exports,
the series, ``metrics.json``). Renders and exports go through the model package
(``engine/model/``).

The recorder observes the model and never changes it; the loop decides when to record.
"""

from __future__ import annotations

import json
import logging
import math
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import torch
from torch import Tensor

from sparsesplat.api.renders import EMPTY_RENDER_COVERAGE
from sparsesplat.engine.camera import Camera
from sparsesplat.engine.color.models import ColorModel, NeuralColor
from sparsesplat.engine.gaussians import Gaussians
from sparsesplat.engine.metrics.evaluate import PSNR_CEILING, Evaluator, LpipsMode
from sparsesplat.engine.metrics.image import masked_psnr, psnr, quantize
from sparsesplat.engine.model.export import export_model
from sparsesplat.engine.model.raster import Raster
from sparsesplat.engine.model.render import render_view, view_colors
from sparsesplat.engine.report import write_report
from sparsesplat.engine.scene import Scene
from sparsesplat.engine.train.config import RecordConfig
from sparsesplat.engine.train.loop.progress import ProgressRecord

log = logging.getLogger(__name__)

BACKGROUND_MARGIN_DB = 0.5
"""A held-out PSNR within this of the constant-background image's is no better than an empty
model (the run warns)."""


def json_safe(value: Any) -> Any:
    """``value`` with every non-finite float replaced by None (JSON has no Infinity/NaN)."""
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, dict):
        return {k: json_safe(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [json_safe(v) for v in value]
    return value


@dataclass(eq=False)
class Recorder:
    """Evaluates, keeps the error-vs-time series and writes the run's files.

    Hooks: :meth:`add_train_loss` (every iteration), :meth:`record` (when an evaluation is
    due and at the end), :meth:`final_metrics` and :meth:`write_outputs` (at the end)."""

    settings: RecordConfig
    scene: Scene
    """Its held-out views are scored."""
    background: Tensor
    """The run's (3,) colour."""
    raster: Raster
    out_dir: Path | None
    preset: str = "default"
    """The preset name, copied into the metrics."""

    def __post_init__(self) -> None:
        """The series, the per-view results and the loss mean start empty."""
        self.records: list[dict[str, Any]] = []
        """The error-vs-time series (ProgressRecord dicts)."""
        self.view_coverage: dict[str, float] = {}
        """Mean alpha of each view's render at the last evaluation (by view name)."""
        self.view_scores: dict[str, dict[str, float | None]] = {}
        """PSNR, SSIM and LPIPS of each view at the last evaluation (by view name); the final
        evaluation scores every held-out view, so a run's weak views can be found."""
        self.eval_keep: Callable[[Tensor, list[Camera]], Tensor] | None = None
        """Rows an evaluation renders, from the means and the cameras rendered (near-plane
        pruning); None renders every row."""
        self._evaluator: Evaluator | None = None
        self._loss_sum = 0.0
        self._loss_count = 0
        self._background_psnr: float | None = None

    def add_train_loss(self, value: float) -> None:
        """Count one iteration's photometric loss into the next record's mean."""
        self._loss_sum += value
        self._loss_count += 1

    def _views(self, max_views: int | None) -> list[Any]:
        """The held-out views an evaluation scores: all, or at most ``max_views`` of them."""
        views = list(self.scene.test)
        if max_views is not None and len(views) > max_views:
            # Evenly spaced, so an interim curve samples the whole held-out trajectory.
            picks = torch.linspace(0, len(views) - 1, max(1, max_views)).round().long()
            views = [views[int(i)] for i in picks.unique()]
        return views

    def evaluate(
        self, gaussians: Gaussians, color: ColorModel, max_views: int | None = None
    ) -> dict[str, float | None]:
        """Mean held-out metrics (all None when the scene has no held-out views)."""
        return self._evaluate(gaussians, color, self._views(max_views))

    def _evaluate(
        self, gaussians: Gaussians, color: ColorModel, views: list[Any]
    ) -> dict[str, float | None]:
        """Mean metrics over ``views`` (all None for none); each view's scores are kept in
        :attr:`view_scores`."""
        if not views:
            return {"psnr": None, "ssim": None, "lpips": None, "avge": None}
        if self._evaluator is None:
            lpips_mode: LpipsMode = "optional" if self.settings.eval_lpips else "off"
            self._evaluator = Evaluator(lpips_mode=lpips_mode, psnr_ceiling=PSNR_CEILING)
        if self.eval_keep is not None:
            keep = self.eval_keep(gaussians.means, [v.camera for v in views])
            if not bool(keep.all()):
                gaussians = Gaussians({k: p.detach()[keep] for k, p in gaussians.params.items()})
        geo = color.geo_features(gaussians) if isinstance(color, NeuralColor) else None
        colors = view_colors(color, gaussians, geo)
        device = gaussians.means.device
        scores = []
        coverage = []
        with torch.no_grad():
            for v in views:
                cam = v.camera.to(device, torch.float32)
                out = render_view(gaussians, colors, cam, self.background, self.raster)
                image = out.image.permute(1, 2, 0)
                scores.append(self._evaluator.score_view(image, v.image, v.mask, key=v.name))
                coverage.append(float(out.alpha.mean()))
        names = [v.name for v in views]
        self.view_coverage = dict(zip(names, coverage, strict=True))
        self.view_scores = dict(zip(names, scores, strict=True))
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
        empty = sorted(n for n, c in self.view_coverage.items() if c < EMPTY_RENDER_COVERAGE)
        base = self.background_psnr()
        problems = []
        if empty:
            listed = ", ".join(empty[:5])
            problems.append(
                f"{len(empty)} of {len(self.view_coverage)} evaluated views render (nearly) "
                f"empty (under {EMPTY_RENDER_COVERAGE:.0%} of pixels covered: {listed})"
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

    def record(
        self,
        iteration: int,
        elapsed_s: float,
        gaussians: Gaussians,
        color: ColorModel,
        final: bool = False,
    ) -> list[ProgressRecord]:
        """Evaluate and append the records of one evaluation: an interim one on at most
        ``eval_max_views`` views, or at the end the final one on every held-out view.

        Where the interim records score a subset, the end appends two: first the interim
        subset's mean of the same evaluation (no extra render), then the final record. So the
        curve keeps one set of views to its end, and the step to the all-view figure is not
        read as progress made in the last seconds."""
        t0 = time.perf_counter()
        interim = self._views(self.settings.eval_max_views)
        scored = list(self.scene.test) if final else interim
        m = self._evaluate(gaussians, color, scored)
        eval_s = time.perf_counter() - t0
        loss = self._loss_sum / self._loss_count if self._loss_count else None
        self._loss_sum, self._loss_count = 0.0, 0

        def make(
            scores: dict[str, float | None], views: int, last: bool, s: float
        ) -> ProgressRecord:
            return ProgressRecord(
                iteration=iteration,
                elapsed_s=elapsed_s,
                train_loss=loss,
                psnr=scores["psnr"],
                ssim=scores["ssim"],
                lpips=scores["lpips"],
                avge=scores["avge"],
                n_gaussians=len(gaussians),
                eval_s=s,
                final=last,
                views=views,
            )

        out = [make(m, len(scored), final, eval_s)]
        if final and 0 < len(interim) < len(scored):
            assert self._evaluator is not None  # the final evaluation made it
            subset = self._evaluator.mean([self.view_scores[v.name] for v in interim])
            out.insert(0, make(subset, len(interim), False, 0.0))  # no render of its own
        self.records += [r.to_dict() for r in out]
        if self.out_dir is not None and not final:
            # Keep the on-disk series current so a long run can be followed (and a killed one
            # still leaves its curve); the PNG is drawn once, at the end.
            self.write_series(plot=False)
        return out

    def final_metrics(
        self,
        iteration: int,
        elapsed_s: float,
        gaussians: Gaussians,
        color: ColorModel,
        stopped: bool,
    ) -> dict[str, Any]:
        """The run's metrics from the last record, with coverage and the emptiness warning."""
        last = self.records[-1] if self.records else {}
        metrics: dict[str, Any] = {k: last.get(k) for k in ("psnr", "ssim", "lpips", "avge")}
        metrics.update(
            seconds=elapsed_s,
            iterations=iteration,
            n_gaussians=len(gaussians),
            preset=self.preset,
            stopped=stopped,
            background_psnr=self.background_psnr(),
        )
        if not self.scene.test:  # no held-out views: judge emptiness on the training views
            device = gaussians.means.device
            colors = view_colors(color, gaussians)
            with torch.no_grad():
                self.view_coverage = {
                    v.name: float(
                        render_view(
                            gaussians,
                            colors,
                            v.camera.to(device, torch.float32),
                            self.background,
                            self.raster,
                        ).alpha.mean()
                    )
                    for v in self.scene.train
                }
        if self.view_coverage:
            metrics["coverage"] = sum(self.view_coverage.values()) / len(self.view_coverage)
        if self.scene.test and self.view_scores:
            metrics["views"] = {
                name: {**scores, "coverage": self.view_coverage[name]}
                for name, scores in self.view_scores.items()
            }
        # Before any training step (the first record) a model is no better than the background
        # by construction, and a run that writes nothing is a timing probe of a few
        # iterations: judging either is a false alarm in every healthy job's log.
        trained = (
            self.out_dir is not None
            and bool(self.records)
            and int(self.records[-1].get("iteration", 0)) > 0
        )
        warning = self.emptiness_warning(metrics.get("psnr")) if trained else None
        if warning:  # surfaced by the caller (the CLI prints it, the service stores it)
            log.info("%s: %s", self.scene.name, warning)
            metrics["warnings"] = [warning]
        return metrics

    def write_outputs(
        self,
        metrics: dict[str, Any],
        gaussians: Gaussians,
        color: ColorModel,
        cameras: list[Camera],
        stopped: bool,
    ) -> dict[str, Path]:
        """Exports (finished runs), the series and ``metrics.json`` in ``out_dir``; adds
        ``sh_baking_psnr`` to ``metrics`` for neural colour."""
        assert self.out_dir is not None
        artifacts: dict[str, Path] = {}
        if not stopped and self.settings.export:
            artifacts.update(self.export(metrics, gaussians, color, cameras))
        artifacts.update(self.write_series())
        metrics["series"] = self.records
        path = self.out_dir / "metrics.json"
        # Valid JSON: no bare Infinity/NaN (non-finite figures are written as null).
        path.write_text(json.dumps(json_safe(metrics), indent=1, default=str, allow_nan=False))
        artifacts["metrics"] = path
        del metrics["series"]
        return artifacts

    def write_series(self, plot: bool = True) -> dict[str, Path]:
        """The series as JSON and CSV (and a PNG when ``plot``) in ``out_dir``."""
        assert self.out_dir is not None
        paths = write_report(self.records, self.out_dir, plot=plot)
        return {f"series_{k}": Path(v) for k, v in paths.items()}

    def export(
        self,
        metrics: dict[str, Any],
        gaussians: Gaussians,
        color: ColorModel,
        cameras: list[Camera],
    ) -> dict[str, Path]:
        """.ply and .splat (``engine.model.export``); adds ``sh_baking_psnr`` to ``metrics``
        for neural colour."""
        assert self.out_dir is not None
        out, baking = export_model(self.out_dir, gaussians, color, cameras, self.background)
        if baking is not None:
            # Identical renders give +inf: kept at the held-out PSNR ceiling (valid JSON).
            metrics["sh_baking_psnr"] = min(baking, PSNR_CEILING)
        return out
