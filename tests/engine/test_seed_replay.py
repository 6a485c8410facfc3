"""The suite's seed machinery (tests/conftest.py): fresh seeds, printed on failure, replayable."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

from tests.conftest import SEED_ENV, draw_seed

REPO = Path(__file__).resolve().parents[2]

_FAILING = """
import random
import torch

def test_draws(seed):
    # Fails always; the message shows what the seed drew from the fixture and the globals.
    drawn = (seed, random.random(), float(torch.rand(())))
    assert False, f"drawn {drawn}"
"""


def test_draw_seed_is_fresh_unless_fixed(monkeypatch: pytest.MonkeyPatch) -> None:
    """Without the variable two draws differ (2^-31 odds of a tie); with it every draw is it."""
    monkeypatch.delenv(SEED_ENV, raising=False)
    assert len({draw_seed() for _ in range(4)}) > 1
    monkeypatch.setenv(SEED_ENV, "123")
    assert draw_seed() == draw_seed() == 123
    monkeypatch.setenv(SEED_ENV, "twelve")
    with pytest.raises(pytest.UsageError, match=SEED_ENV):
        draw_seed()


def _run(folder: Path, env: dict[str, str]) -> str:
    done = subprocess.run(
        [sys.executable, "-m", "pytest", str(folder), "-q", "-p", "no:cacheprovider"],
        cwd=REPO,
        env=env,
        capture_output=True,
        text=True,
    )
    assert done.returncode == 1, done.stdout[-3000:] + done.stderr[-3000:]
    return done.stdout


def test_a_failure_prints_its_seed_and_the_variable_replays_it(tmp_path: Path) -> None:
    """A failing test's report names SPARSESPLAT_TEST_SEED=<n>; running again with it draws the
    same values from the fixture and from Python's and torch's global generators."""
    folder = tmp_path / "suite"
    folder.mkdir()
    # The suite's conftest (fixtures and the report hook) for a test outside the tests folder.
    (folder / "conftest.py").write_text("from tests.conftest import *  # noqa: F403\n"
                                        "from tests.conftest import _seeded_global_generators, "
                                        "pytest_runtest_makereport  # noqa: F401\n")  # fmt: skip
    (folder / "test_draws.py").write_text(_FAILING)
    env = {k: v for k, v in os.environ.items() if k != SEED_ENV}
    env["PYTHONPATH"] = str(REPO)
    first = _run(folder, env)
    found = re.search(rf"{SEED_ENV}=(\d+) replays this run", first)
    assert found, first[-3000:]
    drawn = re.search(r"drawn \((.*?)\)", first)
    assert drawn and drawn.group(1).startswith(found.group(1) + ","), first[-3000:]
    again = _run(folder, env | {SEED_ENV: found.group(1)})
    replayed = re.search(r"drawn \((.*?)\)", again)
    assert replayed and replayed.group(1) == drawn.group(1), (drawn.group(1), again[-3000:])
