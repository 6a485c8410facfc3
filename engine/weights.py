"""Where model weights live and how they are found. Nothing is ever downloaded at run time."""

from __future__ import annotations

import os
from pathlib import Path

from sparsesplat.engine.errors import EngineError

MODELS_DIR_ENV = "SPARSESPLAT_MODELS_DIR"
"""Environment variable naming the models directory (the service settings use the same name)."""

BUNDLED_DIR = Path(__file__).resolve().parent / "priors" / "weights"
"""Weights shipped inside the package (the PyDNet++ depth model)."""


class WeightsNotFound(EngineError, FileNotFoundError):
    """A weights file is not in the models directory."""


def default_models_dir() -> Path:
    """``$SPARSESPLAT_MODELS_DIR``, else ``$XDG_CACHE_HOME/sparsesplat/models``."""
    explicit = os.environ.get(MODELS_DIR_ENV)
    if explicit:
        return Path(explicit).expanduser()
    cache = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache")
    return cache / "sparsesplat" / "models"


def resolve_weight(filename: str, models_dir: Path | None = None) -> Path:
    """Return the path of ``filename`` in ``models_dir`` (default: :func:`default_models_dir`),
    falling back to the bundled weights; raise :class:`WeightsNotFound` naming where it looked."""
    directory = models_dir if models_dir is not None else default_models_dir()
    for candidate in (directory / filename, BUNDLED_DIR / filename):
        if candidate.is_file():
            return candidate
    raise WeightsNotFound(
        f"weights file {filename!r} not found in {directory} (models directory, set with "
        f"{MODELS_DIR_ENV}); run `sparsesplat fetch-weights` where a network exists, "
        "or copy it there"
    )
