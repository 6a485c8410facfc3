"""The error-vs-time report: JSON, CSV and PNG files with the right columns; the text table."""

from __future__ import annotations

import csv
import json
import random
from pathlib import Path

from PIL import Image

from sparsesplat.engine.report import COLUMNS, format_table, split_curve, write_report


def _records(n: int, seed: int) -> list[dict]:
    rng = random.Random(seed)
    return [
        {
            "iteration": 100 * i,
            "elapsed_s": 2.5 * i + rng.random(),
            "train_loss": 1.0 / (i + 1),
            "psnr": 12.0 + i + rng.random(),
            "ssim": 0.4 + 0.01 * i,
            "lpips": None if i == 0 else 0.6 - 0.02 * i,
            "avge": None,
            "n_gaussians": 1000 + rng.randrange(500),
        }
        for i in range(n)
    ]


def test_writes_three_files_with_the_columns(tmp_path: Path, seed: int) -> None:
    records = _records(7, seed)
    records[3]["psnr"] = float("nan")
    records[2]["pass_ms"] = 12.5  # an extra key is kept, after the standard columns
    paths = write_report(records, tmp_path / "out", title="smoke")
    assert set(paths) == {"json", "csv", "png"}
    assert {p.name for p in paths.values()} == {
        "metrics_series.json",
        "metrics_series.csv",
        "metrics_series.png",
    }

    doc = json.loads(paths["json"].read_text())
    assert doc["columns"] == [*COLUMNS, "pass_ms"]
    assert len(doc["records"]) == 7
    assert doc["records"][3]["psnr"] is None  # NaN is not valid JSON: written as null
    assert doc["records"][0]["lpips"] is None
    assert doc["records"][5]["n_gaussians"] == records[5]["n_gaussians"], f"seed {seed}"
    assert doc["records"][2]["pass_ms"] == 12.5 and doc["records"][1]["pass_ms"] is None

    with paths["csv"].open() as f:
        rows = list(csv.DictReader(f))
    assert list(rows[0]) == [*COLUMNS, "pass_ms"]
    assert len(rows) == 7
    assert rows[0]["lpips"] == "" and rows[0]["avge"] == ""
    assert float(rows[6]["elapsed_s"]) == records[6]["elapsed_s"], f"seed {seed}"

    with Image.open(paths["png"]) as im:
        im.load()
        assert im.format == "PNG" and im.width > 100 and im.height > 100


def test_empty_and_metric_free_records_still_plot(tmp_path: Path) -> None:
    paths = write_report([], tmp_path / "empty")
    assert json.loads(paths["json"].read_text())["records"] == []
    with Image.open(paths["png"]) as im:
        assert im.format == "PNG"
    # a user upload without held-out views: only the training loss exists
    recs = [
        {"iteration": i, "elapsed_s": float(i), "train_loss": 1.0 / (1 + i), "n_gaussians": 5}
        for i in range(3)
    ]
    paths = write_report(recs, tmp_path / "no_test")
    with paths["csv"].open() as f:
        assert [r["psnr"] for r in csv.DictReader(f)] == ["", "", ""]


def test_table_is_aligned(seed: int) -> None:
    records = _records(5, seed)
    lines = format_table(records).splitlines()
    assert len(lines) == 2 + 5
    assert len({len(line) for line in lines}) == 1, f"seed {seed}: ragged table\n" + "\n".join(
        lines
    )
    assert lines[0].split() == COLUMNS
    assert lines[2].split()[5] == "-"  # lpips None in the first record
    narrow = format_table(records, ["iteration", "psnr"]).splitlines()
    assert narrow[0].split() == ["iteration", "psnr"]


def test_an_all_view_final_record_is_drawn_apart_from_a_curve_over_fewer_views(
    tmp_path: Path,
) -> None:
    """Interim records on 4 of 8 views, closed by the 4's figure at the end, then the final
    record on all 8: the final one is off the line. Where the curve already scored every view
    (or the records predate ``views``), every record stays on it."""
    curve = [
        {"iteration": 10 * i, "elapsed_s": float(i), "psnr": 15.0 + i, "views": 4, "final": False}
        for i in range(4)
    ]
    final = {"iteration": 30, "elapsed_s": 3.0, "psnr": 20.0, "views": 8, "final": True}
    line, ends, few, every = split_curve([*curve, final])
    assert line == curve and ends == [final] and (few, every) == (4, 8)
    same = [*curve, {**final, "views": 4}]
    assert split_curve(same) == (same, [], 4, 4)
    old = [{k: v for k, v in r.items() if k != "views"} for r in [*curve, final]]
    assert split_curve(old)[:2] == (old, [])
    paths = write_report([*curve, final], tmp_path)  # draws with the legend
    assert Image.open(paths["png"]).size[0] > 0
