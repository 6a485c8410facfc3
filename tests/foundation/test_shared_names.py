"""The names in ``api/names.py`` are the ones every package uses (the engine's included)."""

from __future__ import annotations

import re
from pathlib import Path
from typing import get_args

import pytest

from sparsesplat.api import names
from sparsesplat.api.jobs import JobState

REPO = Path(__file__).resolve().parents[2]


def test_the_engine_config_takes_the_shared_literals() -> None:
    """The trainer accepts exactly the colour models, inits and presets the job spec offers."""
    pytest.importorskip("torch")
    import typing

    from sparsesplat.engine.train.config import presets
    from sparsesplat.engine.train.config import sections as config

    assert typing.get_type_hints(config.ColorConfig)["model"] is names.ColorModelName
    assert typing.get_type_hints(config.InitConfig)["method"] is names.InitName
    assert set(presets.PRESETS) == set(get_args(names.PresetName))


def test_the_job_spec_uses_the_shared_literals() -> None:
    from sparsesplat.api import jobs

    assert jobs.PresetName is names.PresetName
    assert jobs.ColorModelName is names.ColorModelName
    assert jobs.InitName is names.InitName


def test_terminal_states_are_job_states_and_the_web_page_agrees() -> None:
    assert {s.value for s in JobState} > names.TERMINAL_JOB_STATES
    assert {s.value for s in JobState if s.terminal} == names.TERMINAL_JOB_STATES
    script = (REPO / "server" / "static" / "js" / "api.js").read_text()
    found = re.search(r"const TERMINAL = new Set\(\[([^\]]*)\]\)", script)
    assert found, "server/static/js/api.js no longer declares TERMINAL"
    assert set(re.findall(r'"(\w+)"', found.group(1))) == names.TERMINAL_JOB_STATES


def test_artifact_files_and_export_suffixes_agree() -> None:
    """Each export format is the artifact of the same kind, downloaded with its suffix."""
    for fmt in get_args(names.ExportFormat):
        assert Path(names.ARTIFACT_FILES[fmt]).suffix == names.EXPORT_SUFFIXES[fmt]
    assert set(names.EXPORT_SUFFIXES) == set(get_args(names.ExportFormat))


def test_the_engine_writes_the_shared_artifact_names() -> None:
    pytest.importorskip("torch")
    from sparsesplat.engine.commands import render
    from sparsesplat.engine.model import checkpoint

    assert names.ARTIFACT_FILES["checkpoint"] == checkpoint.CHECKPOINT_NAME
    assert set(render.IMAGE_SUFFIXES) == set(names.IMAGE_OUTPUT_SUFFIXES)
