"""``sparsesplat scene info`` through the real command: background, layout and preset shown;
bad scenes exit 2 with the schema's message."""

from __future__ import annotations

import json
from pathlib import Path

from tests.cli.conftest import run_cli, strict_json
from tests.cli.scenes import write_object_scene


def test_info_shows_background_layout_and_preset(tmp_path: Path) -> None:
    scene = write_object_scene(tmp_path / "s", size=24)
    text = run_cli("scene", "info", str(scene), "--prior", "none")
    assert text.returncode == 0, text.stderr
    assert "background [1.0, 1.0, 1.0] (images have alpha: composited on white" in text.stdout
    assert "cameras    inward-looking" in text.stdout
    assert "preset     object (the images have alpha" in text.stdout
    as_json = run_cli("scene", "info", str(scene), "--prior", "none", "--json")
    info = strict_json(as_json.stdout)
    assert isinstance(info, dict)
    assert info["alpha"] is True and info["background"] == [1.0, 1.0, 1.0]
    assert info["preset"] == "object" and info["layout"]["kind"] == "inward-looking"


def test_info_on_a_bad_cameras_file_exits_2(tmp_path: Path) -> None:
    scene = write_object_scene(
        tmp_path / "s", size=24, edit=lambda m: m.update(convension=m.pop("convention"))
    )
    result = run_cli("scene", "info", str(scene), "--prior", "none")
    assert result.returncode == 2
    assert "did you mean 'convention'?" in result.stderr and "Traceback" not in result.stderr
    (scene / "cameras.json").write_text(json.dumps({"frames": []})[:-3])
    result = run_cli("scene", "info", str(scene), "--prior", "none")
    assert result.returncode == 2 and "cannot parse JSON" in result.stderr
