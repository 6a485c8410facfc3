"""``make bench-quality``: train scenes with the paper protocol and tabulate held-out quality.

For every scene (default: every scene under ``<repo>/../shared/data`` or
``$SPARSESPLAT_SHARED_DATA``) and every variant, train with the preset of the scene's format
and record views, iterations, seconds, Gaussians, PSNR, SSIM, LPIPS and AVGE. Variants:

- ``full``: the preset as is (its default depth prior);
- ``no_depth``: the same without depth regularization (``depth_prior='none'``);
- ``prior:KIND``: the full method with the depth prior KIND (``pydnet``, ``plane_sweep``, ...;
  ``prior:user`` with ``--depth-dir DIR``: the depth maps ``DIR/<scene>/<view>.npy``, e.g. the
  reference depths of ``make bench-reference-depth``);
- ``iters:N``: the preset's whole reference schedule compressed to N iterations (this
  variant's length wins over ``--iterations``);
- ``set:FIELD=JSON+FIELD=JSON``: the preset with these TrainConfig overrides (one part
  switched on or off, a schedule field, ...), e.g. ``set:dropout=true`` or
  ``set:depth_prior="none"+color_model="sh"``.

Every entry trains the preset's default run length (``PRESET_ITERATIONS``) unless
``--iterations`` or ``iters:N`` asks for another; either compresses the preset's reference
schedule.

``--seeds 0,1,2`` trains every entry once per seed; the summary table gives the mean and
standard deviation over seeds (run-to-run spread with 3 views is about 1 dB, as large as many
effects). Each row also records the best interim held-out PSNR and the training seconds at
which it was first reached (error against run time decides schedules). ``--merge`` combines
result files written by sweeps run in parallel.

A variant whose effective configuration equals one already trained for that scene (``full``
and ``prior:<preset default>``) reuses that run's row instead of training twice.

A full sweep takes hours on 2 cores, so the results file is rewritten after every (scene,
variant) and a rerun skips entries already in it with the same views and iterations (``--fresh``
retrains them). Run it in the background, e.g.
``nohup python -m benchmarks.quality --iterations 1000 > quality.log 2>&1 &``.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from benchmarks.common import format_table, machine_info, results_dir

COLUMNS = [
    "scene",
    "variant",
    "seed",
    "views",
    "iterations",
    "seconds",
    "gaussians",
    "psnr",
    "ssim",
    "lpips",
    "avge",
    "best_psnr",
    "best_at_s",
]
"""Table columns, in order (rows also carry prior, format, sh_baking_psnr, wall_s, error)."""

SUMMARY_METRICS = ("psnr", "ssim", "lpips", "seconds", "gaussians", "best_psnr", "best_at_s")
"""Figures averaged over seeds in the summary table."""

SUMMARY_COLUMNS = ["scene", "variant", "views", "iterations", "seeds", *SUMMARY_METRICS]
"""Summary table columns (each metric as ``mean ± std`` over seeds)."""

DEFAULT_VARIANTS = ("full", "no_depth", "prior:pydnet", "prior:plane_sweep")
"""Variants run when ``--variants`` is not given."""

PRESET_OF_FORMAT = {"llff": "llff", "dtu": "dtu", "blender": "blender"}
"""Preset per scene format (the paper protocol); other formats use ``default``."""


def default_data_root() -> Path:
    """``$SPARSESPLAT_SHARED_DATA`` or ``<repo>/../shared/data``."""
    env = os.environ.get("SPARSESPLAT_SHARED_DATA")
    if env:
        return Path(env)
    repo = Path(__file__).resolve().parents[1]
    return repo.parent / "shared" / "data"


def use_shared_models() -> None:
    """Point ``$SPARSESPLAT_MODELS_DIR`` at ``<repo>/../shared/models`` when it is unset and
    that folder exists, so LPIPS (and AVGE) are measured without a fetch-weights step."""
    from sparsesplat.engine.weights import MODELS_DIR_ENV

    shared = Path(__file__).resolve().parents[1].parent / "shared" / "models"
    if not os.environ.get(MODELS_DIR_ENV) and shared.is_dir():
        os.environ[MODELS_DIR_ENV] = str(shared)


def find_scenes(roots: Sequence[Path], max_depth: int = 3) -> list[Path]:
    """Scene folders under ``roots`` (a root that is itself a scene counts), sorted by path."""
    from sparsesplat.engine.datasets import detect_format
    from sparsesplat.engine.errors import SceneError

    found: list[Path] = []

    def visit(path: Path, depth: int) -> None:
        try:
            detect_format(path)
            found.append(path)
            return
        except SceneError:
            pass
        if depth < max_depth:
            for child in sorted(p for p in path.iterdir() if p.is_dir()):
                visit(child, depth + 1)

    for root in roots:
        if not root.is_dir():
            raise SystemExit(f"bench-quality: {root} is not a folder")
        visit(root, 0)
    return sorted(dict.fromkeys(found))


def select_scenes(roots: Sequence[Path], names: str = "") -> list[Path]:
    """The scene folders under ``roots`` (:func:`find_scenes`), only those named in the comma
    list ``names`` when it is not empty (the benches' ``--scenes``)."""
    scenes = find_scenes(roots)
    wanted = {s for s in names.split(",") if s}
    return [p for p in scenes if p.name in wanted] if wanted else scenes


def variant_overrides(variant: str) -> dict[str, Any]:
    """The TrainConfig overrides that turn a preset into ``variant``."""
    if variant == "full":
        return {}
    if variant == "no_depth":
        return {"depth.prior": "none"}
    kind, _, rest = variant.partition(":")
    if kind == "prior" and rest:
        return {"depth.prior": rest}
    if kind == "set" and rest:
        from sparsesplat.engine.train.config import ConfigError
        from sparsesplat.engine.train.config.overrides import parse_override

        overrides: dict[str, Any] = {}
        for item in rest.split("+"):
            try:
                key, value = parse_override(item)
            except ConfigError as exc:
                raise SystemExit(f"bench-quality: variant {variant!r}: {exc}") from None
            overrides[key] = value
        return overrides
    raise SystemExit(
        f"bench-quality: unknown variant {variant!r} (full, no_depth, prior:KIND, iters:N, "
        "set:FIELD=JSON)"
    )


def variant_spec(
    name: str, variant: str, seed: int = 0, iterations: int | None = None, **extra: Any
) -> Any:
    """The run recipe's :class:`RunSpec` of ``variant`` of preset ``name``, trained
    ``iterations`` iterations (default: the preset's run length), with ``extra`` overrides
    (the sweep's record settings) on top.

    ``iters:N`` is the preset's reference schedule compressed to N iterations, e.g.
    ``iters:2000`` (it takes precedence over ``iterations``); any other variant is a set of
    field overrides (:func:`variant_overrides`; ``set:iterations=N`` means ``iters:N``)."""
    from sparsesplat.engine.train.run import RunSpec

    kind, _, count = variant.partition(":")
    overrides: dict[str, Any] = {}
    if kind == "iters":
        try:
            iterations = int(count)
        except ValueError:
            raise SystemExit(f"bench-quality: variant {variant!r}: expected iters:N") from None
    else:
        overrides = variant_overrides(variant)
        if "iterations" in overrides:  # the recipe reads it as the run length
            iterations = overrides.pop("iterations")
    return RunSpec(name, {"seed": seed, **overrides, **extra}, iterations)


def variant_config(
    name: str,
    variant: str,
    seed: int = 0,
    iterations: int | None = None,
    scene: Any = None,
    **extra: Any,
) -> Any:
    """The config (validated) the run recipe gives :func:`variant_spec` on ``scene``: with the
    preset's recipe for the training cameras' layout, as ``sparsesplat train`` gives it (None:
    no scene, no layout recipe)."""
    from sparsesplat.engine.train.run import plan_run

    return plan_run(variant_spec(name, variant, seed, iterations, **extra), scene).config


def _entry_key(row: dict[str, Any]) -> tuple[Any, ...]:
    return (row["scene"], row["variant"], row["views"], row["iterations"], row.get("seed", 0))


def best_error(records: list[dict[str, Any]]) -> tuple[float | None, float | None]:
    """The best held-out PSNR in an error-vs-time series and the training seconds at which it
    was first reached (interim records may score a subset of the held-out views)."""
    best: tuple[float | None, float | None] = (None, None)
    for rec in records:
        value = rec.get("psnr")
        if value is not None and (best[0] is None or value > best[0]):
            best = (float(value), float(rec.get("elapsed_s") or 0.0))
    return best


def _mean_std(values: list[float]) -> str:
    if not values:
        return ""
    mean = sum(values) / len(values)
    if len(values) == 1:
        return f"{mean:.4g}"
    var = sum((v - mean) ** 2 for v in values) / (len(values) - 1)
    return f"{mean:.4g} ± {var**0.5:.2g}"


def summarize(rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """One row per (scene, variant, views, iterations): each metric's mean ± sample standard
    deviation over the seeds that trained without error."""
    groups: dict[tuple[Any, ...], list[dict[str, Any]]] = {}
    for row in rows:
        if not row.get("error"):
            key = (row["scene"], row["variant"], row["views"], row["iterations"])
            groups.setdefault(key, []).append(row)
    out = []
    for (scene, variant, views, iterations), members in groups.items():
        summary: dict[str, Any] = {
            "scene": scene,
            "variant": variant,
            "views": views,
            "iterations": iterations,
            "seeds": ",".join(str(r.get("seed", 0)) for r in members),
        }
        for metric in SUMMARY_METRICS:
            values = [float(r[metric]) for r in members if r.get(metric) is not None]
            summary[metric] = _mean_std(values)
            summary[f"{metric}_values"] = values
        out.append(summary)
    return out


def load_rows(path: Path) -> list[dict[str, Any]]:
    """Rows of an earlier (possibly partial) results file; [] when absent or unreadable."""
    try:
        return list(json.loads(path.read_text()).get("rows", []))
    except (OSError, ValueError, AttributeError):
        return []


def _save(path: Path, rows: list[dict[str, Any]]) -> None:
    """Write the results file atomically in the bench-results shape."""
    info = machine_info()
    payload = {
        "machine": info,
        "threads": info.get("torch_threads"),
        "rows": rows,
        "summary": summarize(rows),
    }
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(path.suffix + ".tmp")
    tmp.write_text(json.dumps(payload, indent=2, default=str) + "\n")
    tmp.replace(path)


class _PriorCache:
    """Depth priors per (scene path, kind), computed once per process."""

    def __init__(self) -> None:
        self._cache: dict[tuple[str, str], Any] = {}

    def get(self, scene_path: Path, scene: Any, kind: str) -> Any:
        key = (str(scene_path), kind)
        if key not in self._cache:
            from sparsesplat.engine.priors import compute_priors

            self._cache[key] = compute_priors(scene, kind)
        return self._cache[key]


def run_entry(
    scene_path: Path,
    scene: Any,
    variant: str,
    spec: Any,
    priors: _PriorCache,
    out_dir: Path,
    device: str,
) -> dict[str, Any]:
    """Train one (scene, variant) of the run recipe's ``spec`` and return its table row
    (``error`` set on a failed run)."""
    from sparsesplat.engine.errors import EngineError
    from sparsesplat.engine.train.run import build_run, plan_run

    config = plan_run(spec, scene).config
    row: dict[str, Any] = {
        "scene": scene.name,
        "path": str(scene_path),
        "format": scene.format,
        "variant": variant,
        "prior": config.depth.prior if config.uses_depth else "none",
        "views": len(scene.train),
        "iterations": config.iterations,
        "seed": config.seed,
    }
    t0 = time.perf_counter()
    try:
        # Dense init always back-projects the plane sweep here (what the trainer does for a
        # monocular prior), so a metric prior:user variant changes the depth passes only.
        dense = config.init.method == "dense"
        init_depth = priors.get(scene_path, scene, "plane_sweep") if dense else None
        result = build_run(
            spec,
            scene,
            out_dir=out_dir,
            device=device,
            prior_source=lambda scene, kind: priors.get(scene_path, scene, kind),
            init_depth=init_depth,
        ).trainer.run()
    except EngineError as exc:  # one failed entry must not end a sweep of hours
        row.update(error=f"{type(exc).__name__}: {exc}", wall_s=time.perf_counter() - t0)
        return row
    m = result.metrics
    best_psnr, best_at_s = best_error(result.records)
    row.update(
        seed=config.seed,
        best_psnr=best_psnr,
        best_at_s=best_at_s,
        seconds=result.seconds,
        gaussians=result.n_gaussians,
        psnr=m.get("psnr"),
        ssim=m.get("ssim"),
        lpips=m.get("lpips"),
        avge=m.get("avge"),
        sh_baking_psnr=m.get("sh_baking_psnr"),
        wall_s=time.perf_counter() - t0,
        out_dir=str(out_dir),
    )
    return row


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Command-line options of the quality benchmark."""
    parser.add_argument("paths", nargs="*", type=Path, help="scene folders or folders of scenes")
    parser.add_argument("--scenes", default="", help="comma list: only scenes with these names")
    parser.add_argument(
        "--variants",
        default=",".join(DEFAULT_VARIANTS),
        help="comma list of full, no_depth, prior:KIND, iters:N, set:FIELD=JSON+FIELD=JSON",
    )
    parser.add_argument(
        "--iterations",
        type=int,
        default=None,
        help="run length of every entry but iters:N ones (default: the preset's); the "
        "reference schedule is compressed to it",
    )
    parser.add_argument("--views", type=int, default=None, help="training views (default: paper)")
    parser.add_argument("--out", type=Path, default=None, help="results JSON")
    parser.add_argument("--runs-dir", type=Path, default=None, help="per-run outputs")
    parser.add_argument("--device", default="cpu", help="torch device, e.g. cpu or cuda")
    parser.add_argument("--threads", type=int, default=None, help="torch CPU threads")
    parser.add_argument("--seeds", default="0", help="comma list of trainer seeds, e.g. 0,1,2")
    parser.add_argument("--downscale", type=int, default=1, help="extra image shrink (smoke runs)")
    parser.add_argument(
        "--eval-max-views", type=int, default=4, help="held-out views per interim eval"
    )
    parser.add_argument("--no-export", action="store_true", help="skip .ply/.splat export")
    parser.add_argument(
        "--depth-dir",
        type=Path,
        default=None,
        help="folder of DIR/<scene>/<view>.npy depth maps attached to the training views as "
        "user depth, for prior:user variants (make bench-reference-depth writes one)",
    )
    parser.add_argument("--fresh", action="store_true", help="retrain entries already in --out")
    parser.add_argument(
        "--merge",
        nargs="+",
        type=Path,
        default=None,
        help="combine these result files into --out and print the summary (no training)",
    )


def merge(paths: Sequence[Path], out: Path) -> int:
    """Combine result files (later files win on the same entry) into ``out``; print the
    summary."""
    rows: dict[tuple[Any, ...], dict[str, Any]] = {}
    for path in paths:
        for row in load_rows(path):
            rows[_entry_key(row)] = row
    _save(out, list(rows.values()))
    print(format_table(summarize(list(rows.values())), SUMMARY_COLUMNS))
    print(f"# wrote {out}")
    return 0


def _with_depth_folder(scene: Any, folder: Path) -> Any:
    """``scene`` with the depth maps in ``folder`` attached (bench-quality's --depth-dir)."""
    from sparsesplat.engine.errors import PriorError
    from sparsesplat.engine.priors.user import attach_depth_folder

    try:
        return attach_depth_folder(scene, folder)
    except PriorError as exc:
        raise SystemExit(f"bench-quality: --depth-dir: {exc}") from None


def run(args: argparse.Namespace) -> int:
    """Run the sweep; returns 0 when every entry trained, 1 when some failed."""
    import torch

    from sparsesplat.engine.datasets import load_scene
    from sparsesplat.engine.train.run import plan_run

    if args.threads:
        torch.set_num_threads(args.threads)
    use_shared_models()
    out = args.out or results_dir() / "quality.json"
    if args.merge:
        return merge(args.merge, out)
    runs_dir = args.runs_dir or out.parent / "quality-runs"
    roots = list(args.paths) or [default_data_root()]
    scenes = select_scenes(roots, args.scenes)
    variants = [v.strip() for v in args.variants.split(",") if v.strip()]
    try:
        seeds = [int(s) for s in args.seeds.split(",") if s.strip()]
    except ValueError:
        raise SystemExit(f"bench-quality: --seeds {args.seeds!r}: expected integers") from None
    if not scenes:
        print(f"bench-quality: no scenes found under {', '.join(map(str, roots))}")
        return 1

    rows = [] if args.fresh else [r for r in load_rows(out) if not r.get("error")]
    done = {_entry_key(r) for r in rows}
    priors = _PriorCache()
    failed = 0
    for scene_path in scenes:
        scene = load_scene(scene_path, views=args.views, downscale=args.downscale)
        if args.depth_dir is not None:
            scene = _with_depth_folder(scene, args.depth_dir / scene.name)
        for seed in seeds:
            preset_name = PRESET_OF_FORMAT.get(scene.format, "default")
            trained: dict[str, dict[str, Any]] = {}  # effective config (JSON) -> its row
            for variant in variants:
                spec = variant_spec(
                    preset_name, variant, seed, args.iterations,
                    **{"record.eval_max_views": args.eval_max_views,
                       "record.export": not args.no_export,
                       "record.checkpoint_interval_s": 0.0},
                )  # fmt: skip
                config = plan_run(spec, scene).config
                key = (scene.name, variant, len(scene.train), config.iterations, seed)
                if key in done:
                    print(f"[skip] {scene.name} {variant} seed {seed}: already in {out}")
                    continue
                ident = json.dumps(config.to_dict(), sort_keys=True, default=str)
                if ident in trained:
                    row = dict(
                        trained[ident], variant=variant, same_run_as=trained[ident]["variant"]
                    )
                else:
                    print(f"[run] {scene.name} {variant} seed {seed} ({config.iterations} it)")
                    sys.stdout.flush()
                    run_name = variant.replace(":", "_").replace("=", "-").replace("+", "_")
                    row = run_entry(
                        scene_path,
                        scene,
                        variant,
                        spec,
                        priors,
                        runs_dir / scene.name / f"{run_name}_seed{seed}",
                        args.device,
                    )
                    if row.get("error"):
                        failed += 1
                        print(f"[fail] {scene.name} {variant}: {row['error']}", flush=True)
                    else:
                        trained[ident] = row
                rows = [r for r in rows if _entry_key(r) != key] + [row]
                _save(out, rows)  # partial results after every entry: a sweep can stop any time
                print(format_table([row], COLUMNS), flush=True)
    info = machine_info()
    print(
        f"# quality on {info['cpu']} ({info['cores']} cores, "
        f"torch threads {info.get('torch_threads')})"
    )
    print(format_table(rows, COLUMNS))
    print(format_table(summarize(rows), SUMMARY_COLUMNS))
    print(f"# wrote {out}")
    return 1 if failed else 0


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of ``python -m benchmarks.quality``."""
    parser = argparse.ArgumentParser(prog="bench-quality", description=__doc__.split("\n")[0])
    add_arguments(parser)
    return run(parser.parse_args(argv))


if __name__ == "__main__":
    sys.exit(main())
