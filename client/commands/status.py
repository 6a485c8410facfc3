"""``sparsesplat status JOB``: a job's state, progress and outcome."""

from __future__ import annotations

import argparse

from sparsesplat.api.camera_estimation import CameraEstimation
from sparsesplat.api.jobs import Job
from sparsesplat.client.commands.common import add_job_arguments, client, dump, fmt_seconds, guarded


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The job id."""
    add_job_arguments(parser)


def describe(job: Job) -> str:
    """Human-readable lines for a job."""
    lines = [f"{job.id}  {job.state.value}"]
    if job.queue_position is not None:
        lines.append(f"  queue position  {job.queue_position}")
    p = job.progress
    if p is not None:
        total = f"/{p.total}" if p.total else ""
        lines.append(
            f"  iteration       {p.iteration}{total}  ({fmt_seconds(p.elapsed_s)} elapsed"
            + (f", ~{fmt_seconds(p.eta_s)} left" if p.eta_s else "")
            + ")"
            + (f"  [{p.phase}]" if p.phase else "")
        )
        r = p.last_record
        if r is not None and r.psnr is not None:
            lines.append(f"  held-out PSNR   {r.psnr:.2f} dB (SSIM {r.ssim or 0:.3f})")
    left_out = p.cameras.left_out() if p is not None and p.cameras is not None else []
    if left_out:
        # The photos uploaded minus those the camera estimation could not place.
        lines.append(
            f"  views           {job.n_train_views - len(left_out)} train + {job.n_test_views} "
            f"held out ({len(left_out)} of {job.n_train_views} photos left out: "
            f"{', '.join(left_out)})"
        )
    else:
        lines.append(f"  views           {job.n_train_views} train + {job.n_test_views} held out")
    if p is not None and p.cameras is not None:
        lines += camera_lines(p.cameras)
    if job.error:
        lines.append(f"  error           {job.error}")
    lines += [f"  warning         {message}" for message in job.warnings]
    if job.state.terminal and job.finished_at is not None and job.started_at is not None:
        lines.append(
            f"  ran             {fmt_seconds((job.finished_at - job.started_at).total_seconds())}"
        )
    if job.disk_bytes is not None:
        lines.append(f"  disk            {job.disk_bytes / 1e6:.1f} MB")
    if job.has_model:
        lines.append(f"  model           sparsesplat render {job.id} ... / export {job.id}")
    return "\n".join(lines)


FOCAL = {"given": "focal given", "exif": "focal from EXIF", "guess": "focal guessed"}
"""How each ``CameraEstimation.focal`` reads in the summary line."""


def camera_lines(estimation: CameraEstimation) -> list[str]:
    """The camera estimation of a photos-only job: a summary line, then one line per photo
    (its verified matches, reprojection error and orientation spread, or that it was left out),
    so that a user sees from the terminal which photos were trained on and how firmly each was
    placed (the warning lines say why a photo was left out)."""
    lines = [
        f"  cameras         estimated from the photos: {estimation.views} of "
        f"{len(estimation.photos) or estimation.views} placed, {estimation.points} points, "
        f"{estimation.reprojection_error_px:.2f} px, {estimation.attempt} attempt, "
        f"{FOCAL.get(estimation.focal, estimation.focal)} ({fmt_seconds(estimation.seconds)})"
    ]
    width = max((len(photo.name) for photo in estimation.photos), default=0)
    for photo in estimation.photos:
        head = f"    {photo.name:<{width}}  {photo.matches:>5} matches"
        if not photo.placed:
            # Its reason is the job's warning line (the worker warns for each photo left out).
            lines.append(f"{head}  left out")
            continue
        error = f"{photo.error_px:.2f} px" if photo.error_px is not None else "-"
        spread = f"  ±{photo.rotation_std_deg:.2f}°" if photo.rotation_std_deg is not None else ""
        lines.append(f"{head}  {error}{spread}")
    return lines


def run(args: argparse.Namespace) -> int:
    """Print the job; exit 0 whatever its state (4 when it does not exist)."""

    def body() -> int:
        with client(args) as c:
            job = c.get_job(args.job)
        print(dump(job) if args.json else describe(job))
        return 0

    return guarded(args, body)
