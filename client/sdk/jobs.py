"""Job handles: :class:`JobHandle` and its asyncio twin :class:`AsyncJobHandle`, side by side."""

from __future__ import annotations

import asyncio
from collections.abc import AsyncIterator, Iterator
from pathlib import Path
from typing import TYPE_CHECKING, Generic, TypeVar

from sparsesplat.api.jobs import Event, Job, JobState, Record
from sparsesplat.client.errors import JobFailed, warn_about
from sparsesplat.client.progress import ProgressBar
from sparsesplat.client.scenes import Upload
from sparsesplat.client.sdk._config import EventCallback
from sparsesplat.client.sdk._output import records_frame, write_file
from sparsesplat.client.sdk.models import AsyncModelHandle, ModelHandle

if TYPE_CHECKING:
    import pandas as pd

    # Named as strings in the handles' base classes (the client module imports this one).
    from sparsesplat.client.sdk._client import AsyncClient, Client  # noqa: F401


ClientT = TypeVar("ClientT")


class _JobHandleBase(Generic[ClientT]):
    """What both job handles hold: the client, the job record as last read, the upload."""

    def __init__(self, client: ClientT, info: Job, upload: Upload | None = None) -> None:
        self.client = client
        self.info = info
        """The job record as last read."""
        self.upload = upload
        """What was submitted (when this handle came from a submission)."""

    @property
    def id(self) -> str:
        """Job id (also its model's)."""
        return self.info.id

    @property
    def state(self) -> JobState:
        """State as last read (see ``refresh()``)."""
        return self.info.state

    def _ended(self, job: Job, raise_on_failure: bool) -> Job:
        """The end of ``wait``: warn about the final record ``job``, raise :class:`JobFailed`
        when it did not succeed and ``raise_on_failure``; else return it."""
        warn_about(job, stacklevel=4)  # past _ended and wait, to wait's caller
        if raise_on_failure and job.state != JobState.succeeded:
            raise JobFailed(job)
        return job

    def __repr__(self) -> str:
        return f"{type(self).__name__}({self.id!r}, state={self.state.value!r})"


class JobHandle(_JobHandleBase["Client"]):
    """A submitted job: its latest record in :attr:`info`, and what can be done with it."""

    def refresh(self) -> Job:
        """Read the job record again."""
        self.info = self.client.get_job(self.id)
        return self.info

    def events(self, after: int = 0, *, timeout: float | None = None) -> Iterator[Event]:
        """Stored then live events, resuming after dropped connections (see
        :meth:`Client.events`)."""
        return self.client.events(self.id, after, timeout=timeout)

    def wait(
        self,
        timeout: float | None = None,
        *,
        progress: bool | None = None,
        callback: EventCallback | None = None,
        raise_on_failure: bool = True,
    ) -> Job:
        """Block until the job ends; return its final record.

        Args:
            timeout: seconds to wait at most (:class:`Timeout` after).
            progress: show a tqdm bar (None: when stderr is a terminal).
            callback: called with every event (state, progress, record).
            raise_on_failure: raise :class:`JobFailed` when it ends failed or cancelled.
        """
        bar = ProgressBar(self.id, progress)
        try:
            for event in self.events(timeout=timeout):
                bar.update(event)
                if callback is not None:
                    callback(event)
        finally:
            bar.close()
        return self._ended(self.refresh(), raise_on_failure)

    def metrics(self) -> list[Record]:
        """Held-out error records so far (the error-against-time curve)."""
        return self.client.metrics(self.id)

    def metrics_frame(self) -> pd.DataFrame:
        """:meth:`metrics` as a pandas DataFrame (``pandas`` extra)."""
        return records_frame(self.metrics())

    def metrics_plot(self, path: str | Path) -> Path:
        """Save the server's plot of the error against run time as PNG."""
        return write_file(path, self.client._send(self.client._c_metrics_plot(self.id)))

    def cancel(self) -> Job:
        """Ask the job to stop."""
        self.info = self.client.cancel(self.id)
        return self.info

    def delete(self) -> None:
        """Delete the job and all its files."""
        self.client.delete(self.id)

    @property
    def model(self) -> ModelHandle:
        """The job's model (renders and exports once it has succeeded)."""
        return ModelHandle(self.client, self.id)


class AsyncJobHandle(_JobHandleBase["AsyncClient"]):
    """asyncio twin of :class:`JobHandle`."""

    async def refresh(self) -> Job:
        """See :meth:`JobHandle.refresh`."""
        self.info = await self.client.get_job(self.id)
        return self.info

    def events(self, after: int = 0, *, timeout: float | None = None) -> AsyncIterator[Event]:
        """See :meth:`JobHandle.events`."""
        return self.client.events(self.id, after, timeout=timeout)

    async def wait(
        self,
        timeout: float | None = None,
        *,
        progress: bool | None = None,
        callback: EventCallback | None = None,
        raise_on_failure: bool = True,
    ) -> Job:
        """See :meth:`JobHandle.wait`; ``callback`` may also be a coroutine function."""
        bar = ProgressBar(self.id, progress)
        try:
            async for event in self.events(timeout=timeout):
                bar.update(event)
                if callback is not None:
                    result = callback(event)
                    if asyncio.iscoroutine(result):
                        await result
        finally:
            bar.close()
        return self._ended(await self.refresh(), raise_on_failure)

    async def metrics(self) -> list[Record]:
        """See :meth:`JobHandle.metrics`."""
        return await self.client.metrics(self.id)

    async def metrics_frame(self) -> pd.DataFrame:
        """See :meth:`JobHandle.metrics_frame`."""
        return records_frame(await self.metrics())

    async def metrics_plot(self, path: str | Path) -> Path:
        """See :meth:`JobHandle.metrics_plot`."""
        return write_file(path, await self.client._send(self.client._c_metrics_plot(self.id)))

    async def cancel(self) -> Job:
        """See :meth:`JobHandle.cancel`."""
        self.info = await self.client.cancel(self.id)
        return self.info

    async def delete(self) -> None:
        """See :meth:`JobHandle.delete`."""
        await self.client.delete(self.id)

    @property
    def model(self) -> AsyncModelHandle:
        """See :attr:`JobHandle.model`."""
        return AsyncModelHandle(self.client, self.id)
