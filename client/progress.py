"""The progress bar of ``wait()`` (tqdm), fed by a job's events."""

from __future__ import annotations

import sys
from typing import Any

from sparsesplat.api.jobs import Event


class ProgressBar:
    """A tqdm bar over iterations: total from the first progress event, PSNR of the latest
    held-out record and the state in its postfix. ``enabled=None`` shows it when stderr is a
    terminal."""

    def __init__(self, job_id: str, enabled: bool | None = None) -> None:
        if enabled is None:
            enabled = sys.stderr.isatty()
        self._bar: Any = None
        if enabled:
            from tqdm import tqdm

            self._bar = tqdm(total=None, desc=f"job {job_id}", unit="it", leave=True)
        self._postfix: dict[str, str] = {}

    def update(self, event: Event) -> None:
        """Advance for one event."""
        if self._bar is None:
            return
        data = event.data
        if event.type == "state":
            self._postfix["state"] = str(data.get("state"))
        elif event.type == "progress":
            total = data.get("total")
            if total and self._bar.total != total:
                self._bar.total = int(total)
            iteration = int(data.get("iteration") or 0)
            if iteration > self._bar.n:
                self._bar.update(iteration - self._bar.n)
            if data.get("phase"):
                self._postfix["phase"] = str(data["phase"])
        elif event.type == "record" and data.get("psnr") is not None:
            self._postfix["psnr"] = f"{float(data['psnr']):.2f}"
        self._bar.set_postfix(self._postfix, refresh=True)

    def close(self) -> None:
        """Finish the bar."""
        if self._bar is not None:
            self._bar.close()
            self._bar = None
