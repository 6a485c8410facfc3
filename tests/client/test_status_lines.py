"""``sparsesplat status``'s lines for a photos-only job whose camera estimation left photos out."""

from __future__ import annotations

from typing import Any

from sparsesplat.api.jobs import Job
from sparsesplat.client.commands.status import describe


def _job(photos: list[dict[str, Any]]) -> Job:
    cameras = {
        "views": sum(p["placed"] for p in photos), "points": 900,
        "reprojection_error_px": 0.8, "triangulation_angle_deg": 12.0, "seconds": 3.0,
        "attempt": "learned", "focal": "guess", "photos": photos,
    }  # fmt: skip
    return Job.model_validate(
        {
            "id": "job_1",
            "state": "succeeded",
            "spec": {},
            "created_at": "2026-01-01T00:00:00Z",
            "n_train_views": len(photos),
            "n_test_views": 0,
            "progress": {"cameras": cameras},
        }
    )


def _photo(name: str, placed: bool) -> dict[str, Any]:
    return {"name": name, "placed": placed, "matches": 500 if placed else 0}


def test_views_line_counts_the_photos_trained_on_and_names_those_left_out() -> None:
    job = _job([_photo("a.png", True), _photo("b.png", True), _photo("c.png", True),
                _photo("stray.png", False)])  # fmt: skip
    assert job.progress is not None and job.progress.cameras is not None
    assert job.progress.cameras.left_out() == ["stray.png"]
    views = [line for line in describe(job).splitlines() if line.strip().startswith("views")]
    assert views == ["  views           3 train + 0 held out (1 of 4 photos left out: stray.png)"]


def test_views_line_unchanged_when_every_photo_is_placed() -> None:
    job = _job([_photo(f"{i}.png", True) for i in range(3)])
    assert "  views           3 train + 0 held out" in describe(job).splitlines()


def test_camera_lines_show_each_photos_matches_and_error_and_which_were_left_out() -> None:
    placed = {"name": "a.png", "placed": True, "matches": 812, "points": 760, "error_px": 0.557,
              "rotation_std_deg": 0.22}  # fmt: skip
    left = {"name": "stray.png", "placed": False, "matches": 3,
            "reason": "shares no verified match with the placed photos"}  # fmt: skip
    lines = describe(_job([placed, _photo("b.png", True), _photo("c.png", True), left]))
    rows = lines.splitlines()
    summary = [row for row in rows if row.strip().startswith("cameras")]
    assert summary == [
        "  cameras         estimated from the photos: 3 of 4 placed, 900 points, 0.80 px, "
        "learned attempt, focal guessed (3s)"
    ]
    assert "    a.png        812 matches  0.56 px  ±0.22°" in rows
    assert "    b.png        500 matches  -" in rows  # placed, with no error reported
    assert "    stray.png      3 matches  left out" in rows


def test_no_camera_lines_for_a_job_with_uploaded_cameras() -> None:
    job = _job([_photo("a.png", True)])
    assert job.progress is not None
    job.progress.cameras = None
    assert not any(row.strip().startswith("cameras") for row in describe(job).splitlines())
