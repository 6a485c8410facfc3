"""Submission-to-first-event and render latency, measured the same way on both backends.

    python -m tests.distributed.bench_latency [--jobs 5] [--renders 30]

For each backend (embedded: SQLite + polling workers; celery: PostgreSQL + Redis + Celery
nodes) it starts ``sparsesplat serve`` with one training worker and one render worker, with the
default lease, heartbeat and poll settings, and waits until the training worker is idle. Then,
``--jobs`` times, it submits a smoke-scale job (mic 100x100, SH colour, no prior) to an idle
worker and times, from just before the POST:

- ``running``: the job's ``running`` event (a worker claimed it), by its stored time;
- ``first progress``: the first ``progress`` event (iterations under way), stored time;
- ``first progress seen``: when that event reached a WebSocket client opened right after
  the submission (adds the event route's polling);
- ``first record``: the first held-out evaluation record (after ``record_interval_s`` = 2 s
  of training; progress events come with the worker's heartbeat, every ``heartbeat_s`` = 5 s);

and ``--renders`` sequential renders of a held-out camera of a trained model, at 100x100 and
at 504x378 (PNG over HTTP; the first render of a model, which loads it, reported apart).
Prints a table and writes bench-results/latency-backends.json. Not part of the test suite.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

import httpx
from websockets.sync.client import connect

from tests.distributed.servers import PostgresServer, RedisServer
from tests.service.live import FAST_SPEC, LiveService, submit, wait_state
from tests.service.scenes import write_mic_upload

DEFAULTS = {  # the shipped defaults (LiveService's test settings shorten them)
    "SPARSESPLAT_HEARTBEAT_S": "5",
    "SPARSESPLAT_LEASE_S": "30",
    "SPARSESPLAT_POLL_S": "1",
    "SPARSESPLAT_CHECKPOINT_INTERVAL_S": "120",
    "SPARSESPLAT_WORKERS": "1",
    "SPARSESPLAT_RENDER_WORKERS": "1",
    "SPARSESPLAT_RENDERS_PER_SECOND": "1000",
}


def _train_workers(live: LiveService) -> list[tuple[int, str | None]]:
    import sqlalchemy as sa

    from sparsesplat.api.store.database import make_engine

    url = live.env.get("SPARSESPLAT_DATABASE_URL") or f"sqlite:///{live.data_dir}/sparsesplat.db"
    engine = make_engine(url)
    try:
        with engine.begin() as conn:
            rows = conn.execute(
                sa.text("SELECT pid, job_id FROM workers WHERE kind='train' AND heartbeat_at > :t"),
                {"t": time.time() - 30},
            ).all()
    finally:
        engine.dispose()
    return [(int(r.pid), r.job_id) for r in rows]


def _wait_idle(live: LiveService, timeout: float = 600) -> None:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if any(job is None for _, job in _train_workers(live)):
            return
        time.sleep(0.2)
    raise TimeoutError("no idle training worker")


def _one_job(live: LiveService, upload: Path) -> dict[str, float]:
    t0 = time.time()
    job = submit(live.url, upload, {**FAST_SPEC, "iterations": 200})
    seen: dict[str, float] = {}

    def listen() -> None:
        url = live.url.replace("http://", "ws://") + f"/v1/jobs/{job['id']}/events?after=0"
        with connect(url, open_timeout=30) as ws:
            for message in ws:
                event = json.loads(message)
                if event["type"] == "progress" and "progress" not in seen:
                    seen["progress"] = time.time()

    listener = threading.Thread(target=listen, daemon=True)
    listener.start()
    done = wait_state(live.url, job["id"], {"succeeded", "failed", "cancelled"}, timeout=600)
    assert done["state"] == "succeeded", done
    listener.join(timeout=30)
    url = live.url.replace("http://", "ws://") + f"/v1/jobs/{job['id']}/events?after=0"
    with connect(url, open_timeout=30) as ws:
        events = [json.loads(m) for m in ws]

    def stored(kind: str, state: str | None = None) -> float:
        from datetime import datetime

        for e in events:
            if e["type"] == kind and (state is None or e["data"].get("state") == state):
                return datetime.fromisoformat(e["time"]).timestamp() - t0
        return float("nan")

    return {
        "running_s": stored("state", "running"),
        "first_progress_s": stored("progress"),
        "first_record_s": stored("record"),
        "first_progress_seen_s": seen.get("progress", float("nan")) - t0,
        "job_id": job["id"],  # type: ignore[dict-item]
    }


def _renders(live: LiveService, job_id: str, n: int) -> dict[str, Any]:
    model = httpx.get(f"{live.url}/v1/models/{job_id}", timeout=30).json()
    held = next(c for c in model["cameras"] if c["split"] == "test")
    keys = ("convention", "pose", "matrix", "fx", "fy", "cx", "cy", "width", "height")
    small = {k: held[k] for k in keys}
    scale = 504 / small["width"]
    large = {**small, "width": 504, "height": 378, "fx": small["fx"] * scale,
             "fy": small["fy"] * scale, "cx": 252.0, "cy": 189.0}  # fmt: skip
    out: dict[str, Any] = {}
    with httpx.Client(timeout=120) as client:
        url = f"{live.url}/v1/models/{job_id}/render"
        for name, camera in (("100x100", small), ("504x378", large)):
            times = []
            for _ in range(n + 1):
                t = time.perf_counter()
                r = client.post(url, json={"camera": camera})
                assert r.status_code == 200, r.text
                times.append((time.perf_counter() - t) * 1000)
            rest = sorted(times[1:])
            out[name] = {
                "first_ms": round(times[0], 1),
                "p50_ms": round(statistics.median(rest), 1),
                "p95_ms": round(rest[min(len(rest) - 1, int(0.95 * len(rest)))], 1),
            }
    return out


def run_backend(backend: str, upload: Path, jobs: int, renders: int) -> dict[str, Any]:
    postgres = redis = None
    env = dict(DEFAULTS)
    if backend == "celery":
        postgres, redis = PostgresServer(), RedisServer()
        postgres.start()
        redis.start()
        env |= {
            "SPARSESPLAT_QUEUE": "celery",
            "SPARSESPLAT_DATABASE_URL": postgres.create_database("bench"),
            "SPARSESPLAT_BROKER_URL": redis.url(),
        }
    root = Path(tempfile.mkdtemp(prefix=f"bench-{backend}-"))
    live = LiveService(root / "data", env)
    try:
        live.start_api()
        live.wait_ready(timeout=600)
        results = []
        for _ in range(jobs):
            _wait_idle(live)
            time.sleep(1.0)
            results.append(_one_job(live, upload))
        summary: dict[str, Any] = {"jobs": results}
        for key in ("running_s", "first_progress_s", "first_progress_seen_s", "first_record_s"):
            values = [r[key] for r in results]
            summary[key] = {"median": round(statistics.median(values), 2),
                            "min": round(min(values), 2), "max": round(max(values), 2)}  # fmt: skip
        summary["renders"] = _renders(live, str(results[-1]["job_id"]), renders)
        return summary
    finally:
        live.stop()
        for server in (postgres, redis):
            if server is not None:
                server.close()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--jobs", type=int, default=5)
    parser.add_argument("--renders", type=int, default=30)
    parser.add_argument("--backends", nargs="+", default=["embedded", "celery"])
    args = parser.parse_args()
    upload = write_mic_upload(Path(tempfile.mkdtemp(prefix="bench-mic-")) / "upload", 100)
    report: dict[str, Any] = {
        "machine": platform.processor() or platform.machine(),
        "cpus": os.cpu_count(),
        "load_average_at_start": os.getloadavg(),
        "settings": DEFAULTS,
    }
    for backend in args.backends:
        report[backend] = run_backend(backend, upload, args.jobs, args.renders)
    report["load_average_at_end"] = os.getloadavg()
    print(f"{'':24}" + "".join(f"{b:>22}" for b in args.backends))
    for key in ("running_s", "first_progress_s", "first_progress_seen_s", "first_record_s"):
        row = "".join(f"{report[b][key]['median']:>15.2f} s (med)" for b in args.backends)
        print(f"{key:24}{row}")
    for size in ("100x100", "504x378"):
        for stat in ("first_ms", "p50_ms", "p95_ms"):
            row = "".join(f"{report[b]['renders'][size][stat]:>19.1f} ms" for b in args.backends)
            print(f"render {size} {stat:11}{row}")
    out = Path("bench-results")
    out.mkdir(exist_ok=True)
    (out / "latency-backends.json").write_text(json.dumps(report, indent=1))


if __name__ == "__main__":
    main()
