"""Compile-once, load-many for the engine's C++/OpenMP extensions (rasterizer, projection,
hash grid, photometric loss), and the compiler flags they share.

Each extension is built by ``torch.utils.cpp_extension.load`` at first use and reused by later
processes. The build directory is keyed by content: ``<name>_<key>`` under
``$TORCH_EXTENSIONS_DIR`` (torch's default cache when unset), where ``key`` hashes the sources
and headers, the compiler flags and what the build commands depend on (torch version and
installation path, Python, machine, compiler). The sources are copied into that directory and
compiled from there, so the build commands never mention the checkout's path: checkouts of the
same sources using one virtual environment share one build, and any other checkout or
environment gets its own directory instead of rebuilding this one (torch alone caches by name
only, and its ninja rebuilds whenever the paths in the command lines change). Any change to a
source, header or flag gives a new key and so a fresh build. One loader per extension keeps the
built module and a lock, so concurrent first calls in one process build it once.
"""

from __future__ import annotations

import contextlib
import fcntl
import hashlib
import json
import logging
import os
import platform
import shutil
import sys
import threading
import time
import weakref
from collections.abc import Iterator, Sequence
from pathlib import Path
from types import ModuleType

log = logging.getLogger(__name__)

ISA_CFLAGS = {
    "x86_64": ("-mavx2", "-mfma", "-mf16c"),
    "aarch64": ("-march=armv8-a",),
}
"""The instruction-set flags of the baseline per CPU architecture (``platform.machine()``,
normalized): on x86-64 the x86-64-v3 baseline (AVX2, FMA, F16C), whose AVX-512 kernels live in
translation units of their own, called only when the CPU reports AVX-512 at run time, so the
build stays portable to any x86-64-v3 machine; on aarch64 ARMv8-A, which includes NEON (Apple
Silicon, Graviton), for the portable kernels. Any other architecture gets none: the portable
kernels still build there where the compiler targets the machine, and a failed build falls back
to the torch implementations (:meth:`NativeExtension.load_or_none`)."""
_MACHINE_ALIASES = {"amd64": "x86_64", "arm64": "aarch64"}


def cpu_architecture(machine: str | None = None) -> str:
    """``machine`` (``platform.machine()`` when None) under the names of :data:`ISA_CFLAGS`
    (macOS and Windows say ``arm64`` and ``AMD64``)."""
    name = (platform.machine() if machine is None else machine).lower()
    return _MACHINE_ALIASES.get(name, name)


def baseline_cflags(machine: str | None = None) -> tuple[str, ...]:
    """Compiler flags every extension starts from on ``machine`` (this one when None): -O3,
    the architecture's :data:`ISA_CFLAGS`, OpenMP, no errno from math functions (so they
    vectorize), C++17."""
    isa = ISA_CFLAGS.get(cpu_architecture(machine), ())
    return ("-O3", *isa, "-fopenmp", "-fno-math-errno", "-std=c++17")


BASELINE_CFLAGS = baseline_cflags()
"""This machine's :func:`baseline_cflags`."""
NO_FP_CONTRACT = "-ffp-contract=off"
"""The flag that keeps every ``a * b + c`` two roundings (no fused multiply-add unless the
source writes one), for kernels that must round as their torch reference does."""


def requirements(machine: str | None = None) -> str:
    """What every build needs on ``machine`` (this one when None); it heads the hint of a
    failed build's error."""
    if cpu_architecture(machine) == "x86_64":
        return "needs g++ with AVX2 support and ninja"
    return "needs g++ and ninja"


REQUIREMENTS = requirements()
"""This machine's :func:`requirements`."""
HEADER_SUFFIXES = (".h", ".hpp")
"""Files of the source folder that are hashed and staged besides the listed sources."""
LDFLAGS = ("-fopenmp",)
"""Linker flags of every extension."""
KEY_LENGTH = 16
"""Hex digits of the content hash in the build directory's name (64 bits)."""


def _ensure_ninja_on_path() -> None:
    """torch's builder needs ``ninja``; the venv ships it next to the interpreter."""
    if shutil.which("ninja") is None:
        bindir = str(Path(sys.executable).parent)
        os.environ["PATH"] = bindir + os.pathsep + os.environ.get("PATH", "")


def staged_files(source_dir: Path, sources: Sequence[str]) -> list[str]:
    """The files a build reads: the sources plus every header in ``source_dir`` (headers are
    not parsed for includes; hashing them all can only rebuild too often, never too rarely)."""
    headers = sorted(p.name for p in source_dir.iterdir() if p.suffix in HEADER_SUFFIXES)
    return [*sources, *[h for h in headers if h not in sources]]


def _toolchain() -> dict[str, str]:
    """What the binary and its build commands depend on besides the sources and flags.

    The paths of the torch installation and of Python's headers are in the build commands
    (include and library paths): two virtual environments with the same torch version would
    otherwise share a directory whose commands differ, and ninja would rebuild on every switch
    (seen: a fresh clone's venv at /tmp/cicheck relinking this checkout's hash grid).
    """
    import sysconfig

    import torch

    return {
        "torch": str(torch.__version__),
        "torch_path": os.path.realpath(os.path.dirname(torch.__file__)),
        "python": sys.implementation.cache_tag or platform.python_version(),
        "python_include": sysconfig.get_paths().get("include", ""),
        "machine": platform.machine(),
        "cxx": os.environ.get("CXX", "c++"),
    }


def _cpu_model() -> str:
    """The CPU's model and flags, for flags that target the build machine (-march=native)."""
    try:
        with open("/proc/cpuinfo", encoding="utf-8") as f:
            lines = [ln for ln in f if ln.startswith(("model name", "flags"))]
        return "".join(sorted(set(lines)))
    except OSError:
        return platform.processor()


BUILD_NOTICE_EVERY_S = 30.0
"""While a first build compiles, a log line this often says it is still going."""


@contextlib.contextmanager
def _building_notice(description: str, build_dir: Path, fresh: bool) -> Iterator[None]:
    """Say a first build has started (it takes minutes: ~2.5 on 2 cores) and, every
    :data:`BUILD_NOTICE_EVERY_S`, that it still runs; a cached load says nothing."""
    if not fresh:
        yield
        return
    log.warning("building the %s (first use only; a few minutes, about 2.5 on 2 cores; "
                "cached in %s)", description, build_dir)  # fmt: skip
    started = time.monotonic()
    done = threading.Event()

    def tick() -> None:
        while not done.wait(BUILD_NOTICE_EVERY_S):
            log.warning("still building the %s (%.0f s so far)", description,
                        time.monotonic() - started)  # fmt: skip

    thread = threading.Thread(target=tick, name="build-notice", daemon=True)
    thread.start()
    try:
        yield
    finally:
        done.set()
    # Reached only when the build succeeded (a failure propagates from the yield).
    log.warning("built the %s in %.0f s", description, time.monotonic() - started)


def build_key(
    source_dir: Path,
    files: Sequence[str],
    cflags: Sequence[str],
    ldflags: Sequence[str] = LDFLAGS,
    toolchain: dict[str, str] | None = None,
) -> str:
    """Content hash of a build: the bytes of ``files`` (relative to ``source_dir``, by name,
    not by path), the flags, and the toolchain (``_toolchain()`` when None). Flags naming the
    build machine's CPU (``-march=native``, ``-mtune=native``) add the CPU model and flags."""
    h = hashlib.sha256()
    for name in files:
        data = (source_dir / name).read_bytes()
        h.update(f"{name}\0{len(data)}\0".encode())
        h.update(data)
    extra = dict(_toolchain() if toolchain is None else toolchain)
    if any("native" in flag for flag in cflags):
        extra["cpu"] = _cpu_model()
    h.update(json.dumps([list(cflags), list(ldflags), extra], sort_keys=True).encode())
    return h.hexdigest()[:KEY_LENGTH]


def extensions_root() -> Path:
    """Where builds go: ``$TORCH_EXTENSIONS_DIR``, else torch's default cache folder (per
    Python version and accelerator, as torch lays it out)."""
    env = os.environ.get("TORCH_EXTENSIONS_DIR")
    if env:
        return Path(env)
    import torch
    from torch.utils import cpp_extension

    accel = f"cu{torch.version.cuda.replace('.', '')}" if torch.version.cuda else "cpu"
    tag = f"py{sys.version_info.major}{sys.version_info.minor}{getattr(sys, 'abiflags', '')}"
    return Path(cpp_extension.get_default_build_root()) / f"{tag}_{accel}"


@contextlib.contextmanager
def _locked(path: Path) -> Iterator[None]:
    """An exclusive file lock across processes (one build or load of an extension at a time);
    the kernel releases it when its holder dies."""
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "a+b") as f:
        fcntl.flock(f, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(f, fcntl.LOCK_UN)


def stage_sources(source_dir: Path, files: Sequence[str], dest: Path) -> None:
    """Copy ``files`` into ``dest``, leaving a file alone when its bytes are already right (its
    modification time is what ninja compares against the objects)."""
    dest.mkdir(parents=True, exist_ok=True)
    for name in files:
        data = (source_dir / name).read_bytes()
        target = dest / name
        if target.is_file() and target.read_bytes() == data:
            continue
        tmp = dest / f".{name}.{os.getpid()}.tmp"
        tmp.write_bytes(data)
        os.replace(tmp, target)


_EXTENSIONS: list[weakref.ref[NativeExtension]] = []
"""Every extension declared in this process, in order (see :func:`loaded_variants`); weak, so
a short-lived one (the build tests' twins) does not outlive its last user."""


def loaded_variants() -> dict[str, str]:
    """Description → instruction-set variant of each native extension this process has loaded
    (e.g. ``{"CPU rasterizer": "avx512"}``); none is built here. Benchmarks record it with the
    machine, since the same CPU runs different kernels when ``SPARSESPLAT_*_ISA`` forces the
    AVX2 baseline, and a figure is only comparable with one taken on the same kernels."""
    live = [e for ref in _EXTENSIONS if (e := ref()) is not None]
    return {e.description: str(m.variant()) for e in live if (m := e.loaded) is not None}


class NativeExtension:
    """A lazily built extension: ``load()`` compiles on the first call and caches the module."""

    def __init__(
        self,
        name: str,
        source_dir: Path,
        sources: Sequence[str],
        cflags: Sequence[str],
        on_failure: type[Exception],
        failure_hint: str,
        description: str,
        fallback: str = "",
    ) -> None:
        """``name`` prefixes the module and build directory names (the content key follows
        it); ``on_failure`` is the typed error raised (with the compiler's output tail) when the
        build fails; its message names :data:`REQUIREMENTS` and then ``failure_hint`` (what to
        do instead, e.g. the switch to a torch implementation; empty for none); ``description``
        names the extension in logs and errors; ``fallback`` says what runs instead when it
        cannot be built and how much slower (see :meth:`load_or_none`)."""
        self.name = name
        self.source_dir = source_dir
        self.sources = tuple(sources)
        self.cflags = tuple(cflags)
        self.on_failure = on_failure
        self.failure_hint = failure_hint
        self.description = description
        self.fallback = fallback
        self._lock = threading.Lock()
        self._module: ModuleType | None = None
        self._failure: Exception | None = None
        _EXTENSIONS.append(weakref.ref(self))

    def files(self) -> list[str]:
        """Sources and headers the build reads (see :func:`staged_files`)."""
        return staged_files(self.source_dir, self.sources)

    def build_name(self) -> str:
        """Module and build-directory name: ``<name>_<content key>``."""
        return f"{self.name}_{build_key(self.source_dir, self.files(), self.cflags)}"

    @property
    def loaded(self) -> ModuleType | None:
        """The module if this process has loaded it already, else None (never builds)."""
        return self._module

    def load_or_none(self) -> ModuleType | None:
        """The compiled module (built on first use), or None where it cannot be built: for the
        callers with a torch implementation to fall back on. The first failure logs one warning
        (what failed on which CPU, ``fallback``, the compiler's last line); the build is not
        tried again in this process, and later calls return None quietly."""
        if self._module is not None:
            return self._module
        if self._failure is not None:
            return None
        try:
            return self.load()
        except self.on_failure as exc:
            with self._lock:
                first = self._failure is None
                self._failure = exc
            if first:
                cause = str(exc).strip().splitlines()[-1:] or [type(exc).__name__]
                log.warning("the %s could not be built on this CPU (%s): %s. Cause: %s",
                            self.description, cpu_architecture(), self.fallback or
                            "no fallback", cause[0][-300:])  # fmt: skip
            return None

    def load(self) -> ModuleType:
        """Return the compiled module, building it on first use."""
        if self._module is not None:
            return self._module
        with self._lock:
            if self._module is not None:
                return self._module
            _ensure_ninja_on_path()
            from torch.utils import cpp_extension

            try:
                name = self.build_name()
                build_dir = extensions_root() / name
                src = build_dir / "src"
                # The whole build-or-load runs under a kernel lock (released when a process
                # dies). torch's own "lock" file is not: a process killed while building leaves
                # it, and every later load would wait for it forever. Holding our lock, nobody
                # else is building, so such a file is stale and goes.
                with _locked(build_dir / "stage.lock"):
                    stage_sources(self.source_dir, self.files(), src)
                    stale = build_dir / "lock"
                    if stale.exists():
                        log.warning("removing a stale build lock left by a killed process: %s",
                                    stale)  # fmt: skip
                        stale.unlink(missing_ok=True)
                    fresh = not any(build_dir.glob(f"{name}*.so"))
                    # Copies: the builder appends its own flags to the lists it is given.
                    with _building_notice(self.description, build_dir, fresh):
                        mod = cpp_extension.load(
                            name=name,
                            sources=[str(src / f) for f in self.sources],
                            extra_cflags=list(self.cflags),
                            extra_ldflags=list(LDFLAGS),
                            extra_include_paths=[str(src)],
                            build_directory=str(build_dir),
                            verbose=False,
                        )
            except Exception as exc:  # the builder raises RuntimeError/CalledProcessError/OSError
                hint = "; ".join(filter(None, (REQUIREMENTS, self.failure_hint)))
                raise self.on_failure(
                    f"building the {self.description} from {self.source_dir} failed "
                    f"({hint}): {str(exc)[-4000:]}"
                ) from exc
            log.info("%s loaded from %s: %s kernels", self.description, build_dir, mod.variant())
            self._module = mod
            return mod
