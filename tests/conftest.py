"""Suite-wide fixtures: random seeds, thread count, the shared real scenes, the models directory.

Random seeds: every test gets a fresh seed (the ``seed`` fixture; Python's ``random``, numpy's and
torch's global generators are seeded from it too), so the suite explores new inputs on each run.
A failing test prints ``SPARSESPLAT_TEST_SEED=<seed>`` in its report; setting that variable
replays the run exactly (it fixes the seed of every test in the run).
"""

from __future__ import annotations

import os
import random
import secrets
import shutil
from collections.abc import Generator, Iterator
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parent.parent
SHARED = REPO.parent / "shared"
SHARED_DATA = SHARED / "data"
SHARED_MODELS = SHARED / "models"
TEST_MODELS_DIR = REPO / ".cache" / "models"
SEED_ENV = "SPARSESPLAT_TEST_SEED"
"""Environment variable that fixes every test's random seed (replays a failure)."""
_SEED_KEY = pytest.StashKey[int]()


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


def draw_seed() -> int:
    """The seed for one test: ``$SPARSESPLAT_TEST_SEED`` when set, else a fresh random one."""
    fixed = os.environ.get(SEED_ENV, "").strip()
    if fixed:
        try:
            return int(fixed, 0)
        except ValueError:
            raise pytest.UsageError(f"{SEED_ENV}={fixed!r}: expected an integer") from None
    return secrets.randbits(31)


@pytest.fixture
def seed(request: pytest.FixtureRequest, _seeded_global_generators: None) -> int:
    """This test's random seed (see the module docstring); a failure report prints it."""
    return request.node.stash[_SEED_KEY]


@pytest.fixture(autouse=True)
def _seeded_global_generators(request: pytest.FixtureRequest) -> None:
    """Draw the test's seed and seed the global generators with it, so code that draws from
    them (torch.rand without a generator, random.random) replays too."""
    value = draw_seed()
    request.node.stash[_SEED_KEY] = value
    random.seed(value)
    try:
        import numpy

        numpy.random.seed(value)
    except ImportError:
        pass
    try:
        import torch

        torch.manual_seed(value)
    except ImportError:
        pass


@pytest.hookimpl(wrapper=True)
def pytest_runtest_makereport(
    item: pytest.Item, call: pytest.CallInfo[None]
) -> Generator[None, pytest.TestReport, pytest.TestReport]:
    """A failed test's report says its seed and how to replay it."""
    report = yield
    value = item.stash.get(_SEED_KEY, None)
    if report.failed and value is not None:
        replay = f"{SEED_ENV}={value} pytest '{item.nodeid}'"
        report.sections.append(("random seed", f"{SEED_ENV}={value} replays this run: {replay}"))
    return report
