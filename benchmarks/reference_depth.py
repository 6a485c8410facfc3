"""``make bench-reference-depth``: how right is a depth prior? Measure it against the depth of a
model fitted to every view of the scene.

With three views nothing in a scene says what its true depth is, so the question "does the
bundled prior agree with the scene?" needs a reference. This benchmark builds one per scene:
it trains the scene's preset without depth (random init) on *all* its posed views (every
training candidate and every held-out view; DTU: the 9 + 25 views of the protocol, Blender:
the 9 + 25), renders that model's depth (alpha-normalised) at the three sparse training
views, and writes it to ``OUT/<scene>/<view>.npy``. Then, per training view, it reports the
Spearman rank correlation of the bundled prior (and of the plane sweep) with that reference
depth, on the pixels the reference model covers (alpha > 0.5).

The reference is a diagnostic, not a prior a user could have: it has seen the held-out views.
Training the sparse-view preset against it (``make bench-quality BENCH_ARGS="--variants
prior:user --depth-dir OUT ..."``) answers whether the method's depth passes pay when the
prior agrees with the scene — i.e. whether a loss against the no-depth baseline is the prior's
doing or the method's.

``--score RUN_DIR ...`` then measures the geometry each trained sparse-view model learned: for
every bench-quality run folder (``RUNS/<scene>/<variant>_seed<N>`` with its ``checkpoint.pt``)
it renders depth at the scene's held-out views and compares it with the all-view model's depth
there (both models live in the same world frame, so depths compare in scene units): the median
relative depth error and the Spearman rank correlation over the pixels both models cover (DTU:
inside the object mask). A depth pass that works moves these towards the reference.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from benchmarks.common import (
    format_table,
    machine_info,
    results_dir,
    write_results,
)
from benchmarks.quality import (
    PRESET_OF_FORMAT,
    default_data_root,
    select_scenes,
    use_shared_models,
)

DEFAULT_ITERATIONS = 3000
"""Run length of the all-view model: each of the 34-71 views is drawn about 40-90 times."""

COVERED_ALPHA = 0.5
"""Pixels where the all-view model's accumulated opacity exceeds this have a reference depth."""

COLUMNS = [
    "scene",
    "view",
    "all_views",
    "fit_psnr",
    "covered",
    "rho_prior",
    "rho_plane_sweep",
    "seconds",
]


def all_view_scene(path: Path) -> tuple[Any, Any]:
    """(sparse scene with the paper's split, the same scene training on every posed view it
    has: the largest training split the format allows plus the held-out views)."""
    from sparsesplat.engine.datasets import load_scene, source_image_count
    from sparsesplat.engine.datasets.splits import (
        BLENDER_TRAIN_ORDER,
        DTU_TRAIN_ORDER,
        LLFF_HOLDOUT,
    )
    from sparsesplat.engine.errors import SceneError

    sparse = load_scene(path)
    pools = {"dtu": len(DTU_TRAIN_ORDER), "blender": len(BLENDER_TRAIN_ORDER)}
    if sparse.format == "llff":
        count = source_image_count(path, "llff")
        pool = count - len(range(0, count, LLFF_HOLDOUT))
    elif sparse.format in pools:
        pool = pools[sparse.format]
    else:
        raise SceneError(f"{path}: reference depth supports LLFF, DTU and Blender scenes")
    widest = load_scene(path, views=pool)
    seen = set(widest.train_indices)
    extra = [(i, v) for i, v in zip(sparse.test_indices, sparse.test, strict=True) if i not in seen]
    dense = dataclasses.replace(
        sparse,
        train=widest.train + [v for _, v in extra],
        train_indices=widest.train_indices + [i for i, _ in extra],
    )
    return sparse, dense


def covered_depth(render: Any) -> tuple[Any, Any]:
    """(float64 alpha-normalised depth, covered mask) of one render: the rasterizer blends
    depth without dividing by alpha; pixels with alpha above :data:`COVERED_ALPHA` count."""
    alpha = render.alpha[0].double()
    return render.depth[0].double() / alpha.clamp_min(1e-6), alpha > COVERED_ALPHA


def reference_depths(trainer: Any, views: Sequence[Any]) -> list[tuple[Any, Any]]:
    """(depth, covered) per view from ``trainer``'s model: the alpha-normalised rendered depth
    where alpha > :data:`COVERED_ALPHA`, elsewhere the farthest covered depth (a prior must be
    defined everywhere: the depth passes use every pixel)."""
    import torch

    out = []
    for view in views:
        depth, covered = covered_depth(trainer.render(view.camera))
        far = float(depth[covered].max()) if bool(covered.any()) else 1.0
        depth = torch.where(covered, depth, torch.full_like(depth, far)).float()
        out.append((depth, covered))
    return out


def measure_scene(
    path: Path, out_dir: Path, iterations: int, prior: str, seed: int
) -> list[dict[str, Any]]:
    """Train the all-view model of one scene, write its depths, return one row per view."""
    import numpy as np

    from sparsesplat.engine.priors import compute_priors
    from sparsesplat.engine.priors.base import PriorDepth
    from sparsesplat.engine.priors.compare import prior_agreement
    from sparsesplat.engine.train.run import RunSpec, build_run

    sparse, dense = all_view_scene(path)
    # The random init named: the all-view camera set's layout recipe does not apply (the
    # reference model is the preset's base recipe without depth, on every protocol view).
    spec = RunSpec(
        PRESET_OF_FORMAT.get(sparse.format, "default"),
        {"seed": seed, "depth_prior": "none", "init": "random", "export": False,
         "checkpoint_interval_s": 0.0},
        iterations,
    )  # fmt: skip
    scene_dir = out_dir / sparse.name
    t0 = time.perf_counter()
    trainer = build_run(spec, dense, out_dir=scene_dir / "run").trainer
    result = trainer.run()
    seconds = time.perf_counter() - t0
    depths = reference_depths(trainer, sparse.train)
    references = [PriorDepth(d, c.float(), metric=True, kind="reference") for d, c in depths]
    priors = {
        "rho_prior": compute_priors(sparse, prior),
        "rho_plane_sweep": compute_priors(sparse, "plane_sweep"),
    }
    rows = []
    for i, (view, reference) in enumerate(zip(sparse.train, references, strict=True)):
        np.save(scene_dir / f"{view.name}.npy", reference.depth.numpy())
        row: dict[str, Any] = {
            "scene": sparse.name,
            "view": view.name,
            "all_views": len(dense.train),
            "iterations": iterations,
            "fit_psnr": result.metrics.get("psnr"),
            "covered": float(reference.confidence.mean()),
            "seconds": seconds,
            "prior": prior,
        }
        for column, kind_priors in priors.items():
            # on the pixels the reference covers and the prior trusts (a monocular prior
            # trusts every pixel; the plane sweep only its confident matches)
            row[column] = prior_agreement(reference, kind_priors[i], threshold=0.5)[0]
        rows.append(row)
    return rows


SCORE_COLUMNS = ["scene", "run", "abs_rel", "rho", "covered", "psnr"]


def held_out_geometry(model: Any, reference: Any, views: Sequence[Any]) -> dict[str, float]:
    """Depth of ``model`` against ``reference`` (both render ``camera``s) at ``views``: the
    median of |d / d_ref - 1| and the Spearman rho over all pixels both cover (alpha above
    :data:`COVERED_ALPHA`; inside ``view.mask`` when the view has one), and the share of the
    reference's covered pixels ``model`` covers too."""
    import torch

    from sparsesplat.engine.priors.compare import spearman

    ours, theirs, both, covered_ref = [], [], 0, 0
    for view in views:
        depth, covered = covered_depth(model.render(view.camera))
        depth_ref, covered_by_ref = covered_depth(reference.render(view.camera))
        if view.mask is not None:
            covered_by_ref &= view.mask.bool()
        used = covered & covered_by_ref & (depth_ref > 0)
        covered_ref += int(covered_by_ref.sum())
        both += int(used.sum())
        ours.append(depth[used])
        theirs.append(depth_ref[used])
    d, d_ref = torch.cat(ours), torch.cat(theirs)
    if not d.numel():
        return {"abs_rel": float("nan"), "rho": float("nan"), "covered": 0.0}
    return {
        "abs_rel": float((d / d_ref - 1).abs().median()),
        "rho": spearman(d, d_ref),
        "covered": both / max(covered_ref, 1),
    }


def score_runs(run_dirs: Sequence[Path], reference_dir: Path) -> list[dict[str, Any]]:
    """One row per bench-quality run folder: its held-out geometry against the reference
    model of its scene (``reference_dir/<scene>/run``, written by this benchmark)."""
    from sparsesplat.engine.datasets import load_scene
    from sparsesplat.engine.model import load_model

    rows, scenes, references = [], {}, {}
    for run in run_dirs:
        name = run.parent.name
        metrics = json.loads((run / "metrics.json").read_text())
        if name not in scenes:
            [path] = select_scenes([default_data_root()], name)
            scenes[name] = load_scene(path)
            references[name] = load_model(reference_dir / name / "run")
        row: dict[str, Any] = {"scene": name, "run": run.name, "psnr": metrics.get("psnr")}
        row.update(held_out_geometry(load_model(run), references[name], scenes[name].test))
        rows.append(row)
        print(format_table([row], SCORE_COLUMNS), flush=True)
    return rows


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of ``python -m benchmarks.reference_depth``."""
    parser = argparse.ArgumentParser(
        prog="bench-reference-depth", description=__doc__.split("\n")[0]
    )
    parser.add_argument("paths", nargs="*", type=Path, help="scene folders or folders of scenes")
    parser.add_argument("--scenes", default="", help="comma list: only scenes with these names")
    parser.add_argument("--iterations", type=int, default=DEFAULT_ITERATIONS, help="run length")
    parser.add_argument("--prior", default="pydnet", help="the prior to compare (default pydnet)")
    parser.add_argument("--seed", type=int, default=0, help="trainer seed of the all-view model")
    parser.add_argument("--threads", type=int, default=None, help="torch CPU threads")
    parser.add_argument(
        "--out-dir",
        type=Path,
        default=None,
        help="depth maps (default bench-results/reference-depth)",
    )
    parser.add_argument("--name", default="reference-depth", help="results name (JSON file)")
    parser.add_argument(
        "--score",
        nargs="+",
        type=Path,
        default=None,
        metavar="RUN_DIR",
        help="instead of training: score these bench-quality run folders' held-out depth "
        "against the reference models in --out-dir",
    )
    args = parser.parse_args(argv)
    import torch

    if args.threads:
        torch.set_num_threads(args.threads)
    use_shared_models()
    out_dir = args.out_dir or results_dir() / "reference-depth"
    if args.score:
        write_results(args.name, score_runs(args.score, out_dir), SCORE_COLUMNS)
        return 0
    scenes = select_scenes(list(args.paths) or [default_data_root()], args.scenes)
    rows: list[dict[str, Any]] = []
    for path in scenes:
        print(f"[run] {path.name} ({args.iterations} iterations on every view)", flush=True)
        scene_rows = measure_scene(path, out_dir, args.iterations, args.prior, args.seed)
        print(format_table(scene_rows, COLUMNS), flush=True)  # a long sweep shows as it goes
        rows += scene_rows
    write_results(args.name, rows, COLUMNS)
    print(json.dumps({"depth_dir": str(out_dir), "machine": machine_info()["cpu"]}))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
