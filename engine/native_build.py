"""Compile-once, load-many for the engine's C++/OpenMP extensions (rasterizer, hash grid).

Each extension is built by ``torch.utils.cpp_extension.load`` at first use into
``$TORCH_EXTENSIONS_DIR`` (torch's default cache when unset); later processes reuse the build
unless sources or flags change. One loader per extension keeps the built module and a lock, so
concurrent first calls in one process build it once.
"""

from __future__ import annotations

import logging
import os
import shutil
import sys
import threading
from collections.abc import Sequence
from pathlib import Path
from types import ModuleType

log = logging.getLogger(__name__)


def _ensure_ninja_on_path() -> None:
    """torch's builder needs ``ninja``; the venv ships it next to the interpreter."""
    if shutil.which("ninja") is None:
        bindir = str(Path(sys.executable).parent)
        os.environ["PATH"] = bindir + os.pathsep + os.environ.get("PATH", "")


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
    ) -> None:
        """``on_failure`` is the typed error raised (with the compiler's output tail) when the
        build fails; ``failure_hint`` is appended to its message; ``description`` names the
        extension in logs and errors."""
        self.name = name
        self.source_dir = source_dir
        self.sources = tuple(sources)
        self.cflags = list(cflags)
        self.on_failure = on_failure
        self.failure_hint = failure_hint
        self.description = description
        self._lock = threading.Lock()
        self._module: ModuleType | None = None

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
                mod = cpp_extension.load(
                    name=self.name,
                    sources=[str(self.source_dir / f) for f in self.sources],
                    extra_cflags=self.cflags,
                    extra_ldflags=["-fopenmp"],
                    extra_include_paths=[str(self.source_dir)],
                    verbose=False,
                )
            except Exception as exc:  # the builder raises RuntimeError/CalledProcessError/OSError
                raise self.on_failure(
                    f"building the {self.description} from {self.source_dir} failed "
                    f"({self.failure_hint}): {str(exc)[-4000:]}"
                ) from exc
            log.info("%s loaded: %s kernels", self.description, mod.variant())
            self._module = mod
            return mod
