"""Suite-wide fixtures: thread count, the shared real scenes, the models directory."""

from __future__ import annotations

import os
import shutil
from collections.abc import Iterator
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parent.parent
SHARED = REPO.parent / "shared"
SHARED_DATA = SHARED / "data"
SHARED_MODELS = SHARED / "models"
TEST_MODELS_DIR = REPO / ".cache" / "models"


def _fill_models_dir() -> None:
    """Link the LPIPS weights from ../shared/models into the test models directory."""
    if "SPARSESPLAT_MODELS_DIR" in os.environ:
        return
    TEST_MODELS_DIR.mkdir(parents=True, exist_ok=True)
    if SHARED_MODELS.is_dir():
        for src in SHARED_MODELS.glob("*.pth"):
            dst = TEST_MODELS_DIR / src.name
            if not dst.exists():
                try:
                    dst.symlink_to(src)
                except OSError:
                    shutil.copy2(src, dst)
    os.environ["SPARSESPLAT_MODELS_DIR"] = str(TEST_MODELS_DIR)


_fill_models_dir()
# CI and the target machines have 2 cores; keep every test honest about that.
os.environ.setdefault("OMP_NUM_THREADS", "2")


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """Skip tests marked ``shared_data`` when ../shared/data is absent, ``cuda`` without a GPU."""
    has_cuda = False
    try:
        import torch

        has_cuda = torch.cuda.is_available()
    except ImportError:
        pass
    for item in items:
        if "shared_data" in item.keywords and not SHARED_DATA.is_dir():
            item.add_marker(pytest.mark.skip(reason=f"{SHARED_DATA} not present"))
        if "cuda" in item.keywords and not has_cuda:
            item.add_marker(pytest.mark.skip(reason="no CUDA GPU available"))


@pytest.fixture(scope="session")
def shared_data() -> Path:
    """Path of ../shared/data (tests using it must be marked ``shared_data``)."""
    if not SHARED_DATA.is_dir():
        pytest.skip(f"{SHARED_DATA} not present")
    return SHARED_DATA


@pytest.fixture(scope="session")
def models_dir() -> Path:
    """The models directory the tests use (LPIPS weights linked from ../shared/models)."""
    return Path(os.environ["SPARSESPLAT_MODELS_DIR"])


@pytest.fixture(autouse=True)
def _two_threads() -> Iterator[None]:
    """Run torch on 2 threads like the target machine (no-op when torch is absent)."""
    try:
        import torch
    except ImportError:
        yield
        return
    previous = torch.get_num_threads()
    torch.set_num_threads(2)
    yield
    torch.set_num_threads(previous)
