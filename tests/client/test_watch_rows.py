"""``sparsesplat watch``'s table rows for record events."""

from __future__ import annotations

from datetime import UTC, datetime

from sparsesplat.api.jobs import Event
from sparsesplat.client.commands.watch import row


def _record(views: int, final: bool, psnr: float) -> Event:
    data = {"iteration": 3000, "elapsed_s": 420.0, "psnr": psnr, "n_gaussians": 69900,
            "views": views, "final": final}  # fmt: skip
    return Event(seq=7, job_id="j", type="record", time=datetime(2026, 11, 28, tzinfo=UTC),
                 data=data)  # fmt: skip


def test_record_rows_name_the_views_they_scored() -> None:
    """The curve's closing record and the final one share an iteration and differ in PSNR:
    the row says which views each scored. A record without ``views`` (an older server) keeps
    the column empty."""
    closing, final = row(_record(4, False, 18.86)), row(_record(5, True, 20.13))
    assert closing[3] == "4 views" and closing[6] == "18.86"
    assert final[3] == "all 5 views" and final[6] == "20.13"
    old = _record(0, True, 20.13)
    del old.data["views"]
    assert row(old)[3] == ""
