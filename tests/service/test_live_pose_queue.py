"""The live view's pose slot: a pose that arrives while another waits replaces it and is
counted as dropped; taking empties the slot. Deterministic, unlike a timing-dependent
end-to-end check of the same rule."""

from __future__ import annotations

import asyncio

from sparsesplat.api.renders import LivePose
from sparsesplat.server.routes.live import _LatestPose

CAMERA = {
    "width": 8, "height": 6, "fx": 10.0, "fy": 10.0, "cx": 4.0, "cy": 3.0,
    "matrix": [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]],
    "convention": "opencv", "pose": "camera_to_world",
}  # fmt: skip


def _pose(t: float) -> LivePose:
    return LivePose.model_validate({"camera": CAMERA, "t": t})


def test_latest_pose_wins_and_overtaken_poses_are_counted() -> None:
    async def scenario() -> None:
        slot = _LatestPose()
        assert slot.take() is None and not slot.ready.is_set()
        slot.put(_pose(1))
        assert slot.ready.is_set()
        taken = slot.take()
        assert taken is not None and taken.t == 1 and slot.dropped == 0
        # Three poses while a render runs: the first two are overtaken.
        for t in (2, 3, 4):
            slot.put(_pose(t))
        taken = slot.take()
        assert taken is not None and taken.t == 4 and slot.dropped == 2
        assert slot.take() is None and not slot.ready.is_set()

    asyncio.run(scenario())
