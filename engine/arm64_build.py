"""Cross-compile every native CPU extension's sources for aarch64: the build check of the ARM64
port on an x86 machine (``make check-arm64-build``).

Each source of each extension (:data:`engine.kernels.KERNELS`) is compiled to an object with
Debian's ``aarch64-linux-gnu-g++``, the aarch64 baseline flags of :mod:`engine.native_build`
and the extension's own extra flags, against this environment's torch and Python headers (they
do not depend on the architecture; nothing is linked, since there is no aarch64 torch here).
What runs on aarch64 is tested under emulation by ``tests/engine/raster/test_arm64_emulated.py``.

Usage: ``python -m sparsesplat.engine.arm64_build [--jobs N]``; exit status 1 if any source
fails (its compiler output is printed).
"""

from __future__ import annotations

import argparse
import importlib
import subprocess
import sys
import sysconfig
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

from sparsesplat.engine.native_build import NativeExtension, baseline_cflags

CXX = "aarch64-linux-gnu-g++"
"""Debian's cross compiler (package g++-aarch64-linux-gnu)."""


def extensions() -> list[NativeExtension]:
    """Every native extension the engine declares (importing their build modules)."""
    from sparsesplat.engine.kernels import KERNELS

    found: list[NativeExtension] = []
    for kernel in KERNELS:
        module = importlib.import_module(kernel.module)
        for value in vars(module).values():
            if isinstance(value, NativeExtension) and value not in found:
                found.append(value)
    return found


def include_dirs() -> list[str]:
    """torch's and Python's header folders (as torch's builder passes them)."""
    from torch.utils import cpp_extension

    return [*cpp_extension.include_paths(), sysconfig.get_paths()["include"]]


def compile_command(ext: NativeExtension, source: str, output: Path) -> list[str]:
    """The aarch64 compile command of one source: the extension's flags with the x86 baseline
    replaced by the aarch64 one, plus what torch's builder adds (PIC, the module name)."""
    x86 = set(baseline_cflags("x86_64"))
    extra = [f for f in ext.cflags if f not in x86]
    includes = [f"-I{d}" for d in [str(ext.source_dir), *include_dirs()]]
    return [
        CXX, *baseline_cflags("aarch64"), *extra, "-fPIC", f"-DTORCH_EXTENSION_NAME={ext.name}",
        "-DTORCH_API_INCLUDE_EXTENSION_H", *includes, "-c", str(ext.source_dir / source),
        "-o", str(output),
    ]  # fmt: skip


def main(argv: list[str] | None = None) -> int:
    """Compile every source; print one line per source, the failures' output, and a summary."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--jobs", type=int, default=2, help="parallel compiles (default 2)")
    args = parser.parse_args(argv)
    jobs = [(ext, src) for ext in extensions() for src in ext.sources]
    started = time.monotonic()
    with tempfile.TemporaryDirectory(prefix="arm64-build-") as tmp:

        def run(job: tuple[NativeExtension, str]) -> tuple[str, int, str, float]:
            ext, src = job
            t0 = time.monotonic()
            out = Path(tmp) / f"{ext.name}-{src}.o"
            done = subprocess.run(compile_command(ext, src, out), capture_output=True, text=True)
            return f"{ext.description}: {src}", done.returncode, done.stderr, time.monotonic() - t0

        with ThreadPoolExecutor(max_workers=max(1, args.jobs)) as pool:
            results = list(pool.map(run, jobs))
    failed = 0
    for what, code, err, seconds in results:
        print(f"{'ok  ' if code == 0 else 'FAIL'} {what} ({seconds:.0f} s)")
        if code != 0:
            failed += 1
            print(err[-3000:])
    total = time.monotonic() - started
    print(f"aarch64 ({CXX}): {len(results) - failed} of {len(results)} sources compiled, "
          f"{total:.0f} s")  # fmt: skip
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
