"""Error against run time: write the trainer's progress records as JSON, CSV and a PNG plot.

A record is one evaluation of a run at some wall-clock time: ``iteration, elapsed_s,
train_loss, psnr, ssim, lpips, avge, n_gaussians`` (metrics are None when the scene has no
held-out views or the metric was not computed). Extra keys are kept and written after the
standard columns; the plot reads two of them, ``final`` and ``views`` (held-out views scored),
to draw an all-view final record apart from a curve over fewer views.
"""

from __future__ import annotations

import csv
import json
import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

COLUMNS = [
    "iteration",
    "elapsed_s",
    "train_loss",
    "psnr",
    "ssim",
    "lpips",
    "avge",
    "n_gaussians",
]
"""The standard record fields, in the order files and tables show them."""

FILENAMES = {
    "json": "metrics_series.json",
    "csv": "metrics_series.csv",
    "png": "metrics_series.png",
}
"""What :func:`write_report` writes into its output folder, by kind."""


def _clean(value: Any) -> Any:
    """JSON-safe scalar: non-finite floats become None, tensors/numpy scalars plain numbers."""
    if hasattr(value, "item") and callable(value.item):
        value = value.item()
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def _columns(records: Sequence[dict[str, Any]]) -> list[str]:
    """Standard columns first, then any extra keys in first-seen order."""
    extra: list[str] = []
    for rec in records:
        extra += [k for k in rec if k not in COLUMNS and k not in extra]
    return COLUMNS + extra


def _series(records: Sequence[dict[str, Any]], key: str) -> tuple[list[float], list[float]]:
    """(seconds, values) of the records where ``key`` holds a finite number."""
    xs, ys = [], []
    for rec in records:
        x, y = _clean(rec.get("elapsed_s")), _clean(rec.get(key))
        if isinstance(x, (int, float)) and isinstance(y, (int, float)):
            xs.append(float(x))
            ys.append(float(y))
    return xs, ys


def split_curve(
    records: Sequence[dict[str, Any]],
) -> tuple[list[dict[str, Any]], list[dict[str, Any]], int, int]:
    """(curve, ends, views on the curve, views at the end): the records a plot joins by a line,
    and the final records it draws apart.

    Interim records score a fixed few held-out views (``views``) and the final one all of them;
    the trainer closes the curve with the few's figure at the end. Where the final record
    scored more views than the curve, it is kept off the line, so the step between the two sets
    of views does not read as progress made in the last seconds. Otherwise every record is on
    the curve and ``ends`` is empty."""
    curve = [r for r in records if not r.get("final")]
    finals = [r for r in records if r.get("final")]
    subset = max((int(r.get("views") or 0) for r in curve), default=0)
    everything = max((int(r.get("views") or 0) for r in finals), default=0)
    if finals and 0 < subset < everything:
        return curve, finals, subset, everything
    return list(records), [], subset, max(subset, everything)


def plot_report(records: Sequence[dict[str, Any]], path: Path, title: str | None = None) -> Path:
    """Plot held-out PSNR and LPIPS (and the training loss) against seconds into a PNG.

    Uses matplotlib's object API on an Agg canvas: no pyplot, no global backend switch, so it
    is safe inside a service process. Panels without data are left out; with no data at all
    the figure says so.
    """
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    panels = [
        (key, label)
        for key, label in (
            ("psnr", "PSNR (dB, held-out) ↑"),
            ("lpips", "LPIPS (held-out) ↓"),
            ("train_loss", "training loss ↓"),
        )
        if _series(records, key)[0]
    ]
    fig = Figure(figsize=(7.0, 2.4 * max(1, len(panels))), dpi=100)
    FigureCanvasAgg(fig)
    axes = fig.subplots(max(1, len(panels)), 1, sharex=True, squeeze=False)[:, 0]
    if not panels:
        axes[0].text(0.5, 0.5, "no records", ha="center", va="center")
    curve, ends, subset, everything = split_curve(records)
    for ax, (key, label) in zip(axes, panels, strict=False):
        held_out = bool(ends) and key != "train_loss"  # the loss is the same on both
        xs, ys = _series(curve if held_out else records, key)
        line_label = f"{subset} of {everything} held-out views" if held_out else None
        ax.plot(xs, ys, marker="o", markersize=3, label=line_label)
        if held_out:
            fx, fy = _series(ends, key)
            ax.plot(
                fx,
                fy,
                linestyle="none",
                marker="*",
                markersize=10,
                color="tab:red",
                label=f"end, all {everything} views",
            )
            ax.legend(loc="best", fontsize="small")
        ax.set_ylabel(label)
        ax.grid(True, alpha=0.3)
    axes[-1].set_xlabel("training seconds (evaluation and checkpoints excluded)")
    if title:
        axes[0].set_title(title)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, format="png")
    return path


def write_report(
    records: Sequence[dict[str, Any]],
    out_dir: str | Path,
    title: str | None = None,
    plot: bool = True,
) -> dict[str, Path]:
    """Write ``metrics_series.{json,csv,png}`` into ``out_dir``; returns their paths by kind.
    ``plot=False`` skips the PNG (the trainer refreshes the tables at every record and draws
    the plot once at the end)."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    columns = _columns(records)
    rows = [{c: _clean(rec.get(c)) for c in columns} for rec in records]
    paths = {kind: out / name for kind, name in FILENAMES.items()}
    paths["json"].write_text(json.dumps({"columns": columns, "records": rows}, indent=1))
    with paths["csv"].open("w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=columns)
        writer.writeheader()
        # None is written as an empty cell, the usual CSV spelling of a missing value.
        writer.writerows({c: ("" if v is None else v) for c, v in row.items()} for row in rows)
    if plot:
        plot_report(records, paths["png"], title)
    else:
        del paths["png"]
    return paths


def _fmt(value: Any) -> str:
    """One table cell: floats to 4 significant decimals, None as '-'."""
    value = _clean(value)
    if value is None:
        return "-"
    if isinstance(value, float):
        return f"{value:.4f}" if abs(value) < 1000 else f"{value:.1f}"
    return str(value)


def format_table(records: Sequence[dict[str, Any]], columns: Sequence[str] | None = None) -> str:
    """The records as an aligned text table (header, rule, one line per record)."""
    cols = list(columns) if columns is not None else _columns(records)
    cells = [[_fmt(rec.get(c)) for c in cols] for rec in records]
    widths = [max([len(c)] + [len(row[i]) for row in cells]) for i, c in enumerate(cols)]
    lines = ["  ".join(c.rjust(w) for c, w in zip(cols, widths, strict=True))]
    lines.append("  ".join("-" * w for w in widths))
    lines += ["  ".join(v.rjust(w) for v, w in zip(row, widths, strict=True)) for row in cells]
    return "\n".join(lines)
