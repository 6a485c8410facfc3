"""Helpers every benchmark shares: a description of the machine and a results writer."""

from __future__ import annotations

import json
import os
import platform
from pathlib import Path
from typing import Any

SHARED_SCENES = {
    "flower": "nerf_llff_data/flower",
    "horns": "nerf_llff_data/horns",
    "mic": "nerf_synthetic/mic",
    "dtu_scan24": "dtu/dtu_scan24",
    "dtu_scan37": "dtu/dtu_scan37",
    "beer_can": "nerf_llff_data/beer_can",
    "juicebox_table": "nerf_llff_data/juicebox_table",
    "fox": "instant_ngp/fox",
}
"""Scene name -> folder under the shared data root (the scenes of ../shared/data)."""
RESULTS_DIR_ENV = "SPARSESPLAT_BENCH_DIR"
"""Environment variable overriding where results are written (default: <repo>/bench-results)."""


def _cpu_model() -> str:
    """The CPU model name from /proc/cpuinfo, or platform.processor() elsewhere."""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


CPU_ID_FIELDS = {
    "vendor_id": "vendor",
    "cpu family": "family",
    "model": "model",
    "stepping": "stepping",
}
"""/proc/cpuinfo keys that identify a CPU generation, and their names in ``machine_info``."""

ISA_FLAGS = ("avx2", "avx512f", "avx512_bf16", "amx_tile")
"""CPU flags that decide which kernel variants and matrix paths a bench exercises."""


def cpu_identity(cpuinfo: str) -> dict[str, Any]:
    """Vendor, family, model, stepping and the :data:`ISA_FLAGS` present, from the text of
    /proc/cpuinfo (its first processor). A hypervisor may report only "AMD EPYC" as the model
    name, which spans five generations of very different speed; these fields tell them apart."""
    ident: dict[str, Any] = {}
    flags: list[str] = []
    for line in cpuinfo.splitlines():
        if not line.strip():
            break  # the first processor's block ends here
        key, _, value = line.partition(":")
        key, value = key.strip(), value.strip()
        if key in CPU_ID_FIELDS:
            ident[CPU_ID_FIELDS[key]] = int(value) if value.isdigit() else value
        elif key == "flags":
            present = set(value.split())
            flags = [f for f in ISA_FLAGS if f in present]
    if ident:
        ident["isa"] = flags
    return ident


def _l3_cache() -> str | None:
    """The L3 cache size Linux reports for CPU 0 (e.g. '32768K'), or None."""
    base = Path("/sys/devices/system/cpu/cpu0/cache")
    try:
        for index in sorted(base.glob("index*")):
            if (index / "level").read_text().strip() == "3":
                return (index / "size").read_text().strip()
    except OSError:
        pass
    return None


def machine_info() -> dict[str, Any]:
    """CPU model and identity (family, model, ISA flags, L3), logical cores, torch threads and
    versions of the process running the bench, and the instruction-set variant of each native
    kernel it has loaded (``kernels``)."""
    try:
        ident = cpu_identity(Path("/proc/cpuinfo").read_text())
    except OSError:
        ident = {}
    info: dict[str, Any] = {
        "cpu": _cpu_model(),
        "cpu_id": ident,
        "l3_cache": _l3_cache(),
        "cores": os.cpu_count(),
        "python": platform.python_version(),
        "platform": platform.platform(),
    }
    try:
        import torch

        info["torch"] = torch.__version__
        info["torch_threads"] = torch.get_num_threads()
        info["cuda"] = torch.cuda.get_device_name(0) if torch.cuda.is_available() else None
    except ImportError:
        info["torch"] = None
    from sparsesplat.engine.native_build import loaded_variants

    info["kernels"] = loaded_variants()
    return info


def results_dir() -> Path:
    """bench-results/ at the repository root (or $SPARSESPLAT_BENCH_DIR, or ./bench-results)."""
    if os.environ.get(RESULTS_DIR_ENV):
        return Path(os.environ[RESULTS_DIR_ENV])
    repo = Path(__file__).resolve().parents[1]
    if (repo / "pyproject.toml").is_file():
        return repo / "bench-results"
    return Path.cwd() / "bench-results"


def format_table(rows: list[dict[str, Any]], columns: list[str]) -> str:
    """Rows as an aligned plain-text table with the given columns (missing cells are blank)."""

    def cell(v: Any) -> str:
        if isinstance(v, float):
            return f"{v:.1f}" if abs(v) >= 10 else f"{v:.3g}"
        return "" if v is None else str(v)

    cells = [[cell(r.get(c)) for c in columns] for r in rows]
    widths = [max([len(c)] + [len(row[i]) for row in cells]) for i, c in enumerate(columns)]
    lines = ["  ".join(c.rjust(w) for c, w in zip(columns, widths, strict=True))]
    lines += ["  ".join(v.rjust(w) for v, w in zip(row, widths, strict=True)) for row in cells]
    return "\n".join(lines)


def write_results(name: str, rows: list[dict[str, Any]], columns: list[str]) -> Path:
    """Print ``rows`` as a table and write bench-results/<name>.json; returns the file path."""
    info = machine_info()
    kernels = ", ".join(f"{k} {v}" for k, v in info["kernels"].items())
    ident = info["cpu_id"]
    generation = (
        f"family {ident['family']} model {ident['model']}, "
        if "family" in ident and "model" in ident
        else ""
    )
    print(
        f"# {name} on {info['cpu']} ({generation}{info['cores']} cores, "
        f"torch {info.get('torch')}" + (f"; kernels: {kernels})" if kernels else ")")
    )
    print(format_table(rows, columns))
    out_dir = results_dir()
    out_dir.mkdir(parents=True, exist_ok=True)
    path = out_dir / f"{name}.json"
    payload = {"machine": info, "threads": info.get("torch_threads"), "rows": rows}
    path.write_text(json.dumps(payload, indent=2) + "\n")
    print(f"# wrote {path}")
    return path


class RowLog:
    """A JSON-lines results file a long benchmark appends to row by row (a run stopped midway
    keeps what it measured), each row also printed as a table line as it comes."""

    def __init__(self, path: Path, header: dict[str, Any], columns: list[str]) -> None:
        """Open ``path`` for appending and write ``header`` (the machine, the settings) first."""
        path.parent.mkdir(parents=True, exist_ok=True)
        self.path = path
        self.columns = columns
        self.rows: list[dict[str, Any]] = []
        self._sink = path.open("a")
        self._sink.write(json.dumps(header, default=str) + "\n")

    def add(self, row: dict[str, Any]) -> None:
        """Append ``row`` to the file (flushed) and print it as one table line."""
        self.rows.append(row)
        self._sink.write(json.dumps(row) + "\n")
        self._sink.flush()
        print(format_table([row], self.columns).splitlines()[1], flush=True)

    def close(self) -> None:
        """Close the file and print every row as one table, with where they were written."""
        self._sink.close()
        print(format_table(self.rows, self.columns))
        print(f"written: {self.path}")
