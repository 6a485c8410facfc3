"""The README is true: its set-up commands are the Makefile's, every file it links exists,
every route it names is served, its SDK example runs as written against a real service (smoke
scale), and the CLI commands it shows work with the exit codes docs/sdk.md promises."""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

from sparsesplat.client import Client, media
from tests.client.conftest import REPO, Server, Trained

shared_data = pytest.mark.shared_data
README = REPO / "README.md"
LINK = re.compile(r"\]\(([^)#\s]+)(?:#[^)]*)?\)")
ROUTE = re.compile(r"\b(GET|POST|DELETE) (/v1/[\w{}/.-]+)")


def test_readme_starts_with_the_two_make_targets() -> None:
    """The set-up block is ``make run`` then ``make test``, both real Makefile targets."""
    block = README.read_text().split("## Set up", 1)[1].split("```", 2)[1]
    commands = [line.split()[:2] for line in block.splitlines()[1:] if line.strip()]
    assert commands == [["make", "run"], ["make", "test"]]
    targets = re.findall(r"^([\w-]+):", (REPO / "Makefile").read_text(), re.M)
    assert {"run", "test"} <= set(targets)


@pytest.mark.parametrize(
    "page", ["README.md", *sorted(p.name for p in (REPO / "docs").glob("*.md"))]
)
def test_every_relative_link_resolves(page: str) -> None:
    path = REPO / page if page == "README.md" else REPO / "docs" / page
    links = [
        m for m in LINK.findall(path.read_text()) if "://" not in m and not m.startswith("mailto:")
    ]
    missing = [link for link in links if not (path.parent / link).exists()]
    assert not missing, f"{page} links to files that do not exist: {missing}"
    if page == "README.md":
        assert len(links) >= 8, "the README links out to the docs"


def _served_routes(data_dir: Path) -> set[tuple[str, str]]:
    """(method, path with every parameter written ``{}``) of each route in the app's OpenAPI
    document (every API route is in it)."""
    pytest.importorskip("fastapi")
    from sparsesplat.api.settings import Settings
    from sparsesplat.server.app import create_app

    app = create_app(Settings(data_dir=data_dir, workers=0, render_workers=0))
    return {
        (method.upper(), re.sub(r"\{[^}]*\}", "{}", path))
        for path, operations in app.openapi()["paths"].items()
        for method in operations
    }


def test_every_route_the_readme_names_is_served(tmp_path: Path) -> None:
    """Including the uploaded photos and the depth priors (an older README said none did)."""
    named = {(m, re.sub(r"\{[^}]*\}", "{}", p)) for m, p in ROUTE.findall(README.read_text())}
    assert ("GET", "/v1/jobs/{}/images/{}") in named and ("GET", "/v1/jobs/{}/priors/{}") in named
    missing = named - _served_routes(tmp_path)
    assert not missing, f"the README names routes the app does not serve: {sorted(missing)}"


def test_the_route_check_can_fail(tmp_path: Path) -> None:
    """A route the app does not have is reported (the check is not vacuous)."""
    assert ("GET", "/v1/jobs/{}/photos/{}") not in _served_routes(tmp_path)


def readme_example() -> str:
    """The first Python block of the README's "Python SDK and CLI" section."""
    text = README.read_text()
    section = text.split("## Python SDK and CLI", 1)[1].split("\n## ", 1)[0]
    match = re.search(r"```python\n(.*?)```", section, re.S)
    assert match, "no python example in the README section"
    return match.group(1)


@shared_data
def test_readme_example_runs_as_written(server: Server, tmp_path: Path) -> None:
    # Run from a folder where ../shared/data resolves as it does from the repository root.
    work = tmp_path / "repo"
    work.mkdir()
    (tmp_path / "shared").symlink_to(REPO.parent / "shared")
    script = work / "example.py"
    script.write_text(readme_example())
    env = {**os.environ, "SPARSESPLAT_URL": server.url}
    done = subprocess.run(
        [sys.executable, str(script)], cwd=work, env=env, capture_output=True, text=True,
        timeout=600,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr[-3000:]
    match = re.search(r"(job_\w+): held-out PSNR ([\d.]+) dB", done.stdout)
    assert match, done.stdout
    print(done.stdout.strip())
    psnr = float(match.group(2))
    with Client(server.url) as client:
        info = client.model(match.group(1)).info()
    assert info.metrics["psnr"] is not None and abs(psnr - info.metrics["psnr"]) < 3.0
    assert psnr > 8.0
    side = media.decode_image((work / "side_by_side.png").read_bytes())
    assert side.size == (200, 100)
    assert (work / "mic.ply").read_bytes().startswith(b"ply")


def _cli(*args: str, url: str, cwd: Path) -> subprocess.CompletedProcess[str]:
    env = {**os.environ, "SPARSESPLAT_URL": url}
    return subprocess.run(
        [sys.executable, "-m", "sparsesplat", *args], cwd=cwd, env=env, capture_output=True,
        text=True, timeout=300,
    )  # fmt: skip


@shared_data
def test_cli_commands_and_exit_codes(trained: Trained, tmp_path: Path) -> None:
    url, job_id = trained.url, trained.job.id
    status = _cli("status", job_id, "--json", url=url, cwd=tmp_path)
    assert status.returncode == 0 and json.loads(status.stdout)["state"] == "succeeded"
    listed = _cli("jobs", "--json", "--state", "succeeded", url=url, cwd=tmp_path)
    assert job_id in [j["id"] for j in json.loads(listed.stdout)]
    watch = _cli("watch", job_id, "--json", url=url, cwd=tmp_path)
    lines = [json.loads(line) for line in watch.stdout.splitlines()]
    assert watch.returncode == 0 and lines[-1]["data"]["state"] == "succeeded"
    assert [e["seq"] for e in lines] == list(range(1, len(lines) + 1))
    table = _cli("watch", job_id, "--after", str(len(lines) - 1), url=url, cwd=tmp_path)
    assert table.stdout.splitlines()[0].split()[:3] == ["seq", "time", "event"]
    assert "succeeded" in table.stdout.splitlines()[-1]
    view = _cli("render", job_id, "--view", "test:1", "-o", "v.webp", url=url, cwd=tmp_path)
    assert view.returncode == 0, view.stderr
    assert media.sniff((tmp_path / "v.webp").read_bytes()) == "webp"
    orbit = _cli("render", job_id, "--orbit", "3", "-o", "orbit", "--json", url=url, cwd=tmp_path)
    assert len(json.loads(orbit.stdout)["files"]) == 3
    export = _cli("export", job_id, "--format", "checkpoint", "-o", "ck.pt", url=url, cwd=tmp_path)
    assert export.returncode == 0 and (tmp_path / "ck.pt").stat().st_size > 0
    # A local checkpoint goes to the engine's own render command.
    camera = trained.upload.test_cameras()[0].model_dump_json()
    local = _cli("render", "ck.pt", "--camera", camera, "-o", "local.png", url=url, cwd=tmp_path)
    assert local.returncode == 0, local.stderr
    assert media.image_size((tmp_path / "local.png").read_bytes()) == (100, 100)
    # Exit codes a script can rely on.
    missing = _cli("status", "job_nope", "--json", url=url, cwd=tmp_path)
    assert missing.returncode == 4
    assert json.loads(missing.stdout)["error"]["code"] == "job_not_found"
    sheared = json.loads(camera)
    sheared["matrix"][0][1] += 0.5
    bad = _cli("render", job_id, "--camera", json.dumps(sheared), "-o", "x.png", url=url,
               cwd=tmp_path)  # fmt: skip
    assert bad.returncode == 2 and "rigid" in bad.stderr
    # --view out of range says the valid range; a local checkpoint needs --camera.
    beyond = _cli("render", job_id, "--view", "test:7", "-o", "x.png", url=url, cwd=tmp_path)
    assert beyond.returncode == 2 and "give test:0 to test:1" in beyond.stderr, beyond.stderr
    local_view = _cli("render", "ck.pt", "--view", "test:0", "-o", "l.png", url=url, cwd=tmp_path)
    assert local_view.returncode == 2 and "--camera FILE" in local_view.stderr
    assert "is required" not in local_view.stderr
    # A camera 1000 units away sees nothing: the service says so, the CLI warns.
    far = json.loads(camera)
    for row in far["matrix"][:3]:
        row[3] *= 1000.0 / max(1e-9, sum(r[3] ** 2 for r in far["matrix"][:3]) ** 0.5)
    away = _cli("render", job_id, "--camera", json.dumps(far), "-o", "far.png", url=url,
                cwd=tmp_path)  # fmt: skip
    assert away.returncode == 0 and "warning: render: the camera sees nothing" in away.stderr
    near = _cli("render", job_id, "--camera", camera, "-o", "near.png", url=url, cwd=tmp_path)
    assert near.returncode == 0 and "warning" not in near.stderr
    down = _cli("jobs", url="http://127.0.0.1:9", cwd=tmp_path)
    assert down.returncode == 9 and "cannot reach" in down.stderr


@shared_data
def test_cli_submit_cancel_delete(server: Server, trained: Trained, tmp_path: Path) -> None:
    """Submit a folder (cameras.json upload written from the shared job), cancel, delete."""
    folder = tmp_path / "upload"
    folder.mkdir()
    upload = trained.upload
    for name, data in upload.images.items():
        (folder / name).write_bytes(data)
    (folder / "cameras.json").write_text(json.dumps(upload.cameras))
    # A time budget longer than the test, so that the cancel finds the job queued or running:
    # 5 iterations could end before the cancel command started on a fast machine (a cancel
    # leaves a finished job as it is).
    submitted = _cli("submit", str(folder), "--time-budget", "600", "--json", url=server.url,
                     cwd=tmp_path)  # fmt: skip
    assert submitted.returncode == 0, submitted.stderr
    job = json.loads(submitted.stdout)
    assert (job["n_train_views"], job["n_test_views"]) == (3, 2)
    cancelled = _cli("cancel", job["id"], "--json", url=server.url, cwd=tmp_path)
    assert json.loads(cancelled.stdout)["state"] in ("cancelled", "running")
    images = [str(folder / n) for n in upload.images]
    cameras_file = str(folder / "cameras.json")
    files = _cli("submit", *images, "--cameras", cameras_file, "--iterations", "5",
                 url=server.url, cwd=tmp_path)  # fmt: skip
    assert files.returncode == 0 and files.stdout.strip().startswith("job_")
    for job_id in (job["id"], files.stdout.strip()):
        assert _cli("delete", job_id, url=server.url, cwd=tmp_path).returncode == 0
        assert _cli("status", job_id, url=server.url, cwd=tmp_path).returncode == 4
    # --wait with stdout not a terminal: the id on stdout, the end of the run on stderr.
    waited = _cli("submit", str(folder), "--iterations", "5", "--wait", url=server.url,
                  cwd=tmp_path)  # fmt: skip
    assert waited.returncode == 0, waited.stderr
    assert waited.stdout.strip().startswith("job_")
    assert f"{waited.stdout.strip()}  succeeded" in waited.stderr
    assert "held-out PSNR" in waited.stderr, waited.stderr
    refused = _cli("submit", str(tmp_path / "nothing"), url=server.url, cwd=tmp_path)
    assert refused.returncode == 2 and "not found" in refused.stderr
