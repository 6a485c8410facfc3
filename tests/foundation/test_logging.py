"""One JSON object per line; the job id rides along on every line inside a job context."""

from __future__ import annotations

import io
import json
import logging
import threading

from sparsesplat.api.logs import configure_logging, current_job_id, job_context


def _lines(stream: io.StringIO) -> list[dict]:
    return [json.loads(line) for line in stream.getvalue().splitlines()]


def test_json_lines_carry_job_id_and_extras() -> None:
    stream = io.StringIO()
    configure_logging("INFO", json_lines=True, stream=stream)
    log = logging.getLogger("sparsesplat.worker.test")
    log.info("before")
    with job_context("job-42"):
        assert current_job_id() == "job-42"
        log.info("training step", extra={"iteration": 7, "psnr": 21.5})
        logging.getLogger("some.library").warning("library line")
    log.info("after")
    lines = _lines(stream)
    assert [line["event"] for line in lines] == ["before", "training step", "library line", "after"]
    assert "job_id" not in lines[0] and "job_id" not in lines[3]
    assert lines[1]["job_id"] == "job-42" and lines[2]["job_id"] == "job-42"
    assert lines[1]["iteration"] == 7 and lines[1]["psnr"] == 21.5
    assert lines[2]["level"] == "warning"


def test_job_ids_do_not_leak_between_threads() -> None:
    stream = io.StringIO()
    configure_logging("INFO", json_lines=True, stream=stream)
    log = logging.getLogger("sparsesplat.worker.test")
    barrier = threading.Barrier(2)

    def work(job: str) -> None:
        with job_context(job):
            barrier.wait()
            log.info("tick", extra={"who": job})

    threads = [threading.Thread(target=work, args=(f"job-{i}",)) for i in range(2)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    for line in _lines(stream):
        assert line["job_id"] == line["who"]


def test_exceptions_stay_on_one_line() -> None:
    stream = io.StringIO()
    configure_logging("INFO", json_lines=False, stream=stream)
    try:
        raise ValueError("boom\nsecond line")
    except ValueError:
        logging.getLogger("x").exception("failed")
    assert len(stream.getvalue().strip().splitlines()) == 1
    assert "boom" in stream.getvalue()


def test_a_job_id_given_with_the_call_is_kept_in_both_formats() -> None:
    """The dispatcher logs about queued jobs outside any job context, naming the job with
    ``extra={"job_id": ...}``: the line carries it (the context's None must not replace it)."""
    for json_lines in (True, False):
        stream = io.StringIO()
        configure_logging("INFO", json_lines=json_lines, stream=stream)
        log = logging.getLogger("sparsesplat.dispatch")
        log.warning("sent again", extra={"job_id": "job-7"})
        with job_context("job-8"):
            log.info("inside")
        text = stream.getvalue().splitlines()
        if json_lines:
            assert [json.loads(line).get("job_id") for line in text] == ["job-7", "job-8"]
        else:
            assert "job_id=job-7" in text[0] and "job_id=job-8" in text[1], text
