"""``with`` / ``async with`` support for the SDK's objects that hold a connection: leaving the
block closes it. Each class keeps its own ``__enter__`` (a client returns itself, a live view
connects first)."""

from __future__ import annotations

from types import TracebackType


class ClosesOnExit:
    """Mixin: ``__exit__`` calls :meth:`close`."""

    def close(self) -> None:
        """Release the connection (the class using the mixin implements it)."""
        raise NotImplementedError

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()


class AsyncClosesOnExit:
    """Mixin: ``__aexit__`` awaits :meth:`aclose`."""

    async def aclose(self) -> None:
        """Release the connection (the class using the mixin implements it)."""
        raise NotImplementedError

    async def __aexit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        await self.aclose()
