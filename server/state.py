"""Everything a request handler needs, built once per application (never module globals)."""

from __future__ import annotations

from dataclasses import dataclass

import sqlalchemy as sa

from sparsesplat.api.settings import Settings
from sparsesplat.api.storage import Storage
from sparsesplat.api.store.database import make_engine, migrate
from sparsesplat.api.store.jobs import JobStore
from sparsesplat.api.store.keys import KeyStore
from sparsesplat.api.store.workers import WorkerRegistry
from sparsesplat.server.job_dispatch import JobDispatcher, make_dispatcher
from sparsesplat.server.observability import ServiceMetrics
from sparsesplat.server.ratelimit import RateLimiter
from sparsesplat.server.render_dispatch import RenderDispatcher


@dataclass
class ServiceState:
    """The service's connections and helpers, hung on ``app.state.service``."""

    settings: Settings
    """Configuration."""
    engine: sa.Engine
    """Database engine."""
    jobs: JobStore
    """Job records and events."""
    keys: KeyStore
    """API keys."""
    workers: WorkerRegistry
    """Live workers."""
    storage: Storage
    """Job files."""
    dispatch: JobDispatcher
    """How queued jobs reach the training workers."""
    renders: RenderDispatcher
    """Where render requests go."""
    render_limit: RateLimiter
    """Renders per second per key."""
    metrics: ServiceMetrics
    """Prometheus metrics."""

    @classmethod
    def open(cls, settings: Settings) -> ServiceState:
        """Connect to the database (migrating it) and storage named by ``settings``."""
        assert settings.database_url is not None
        engine = make_engine(settings.database_url)
        migrate(engine)
        jobs = JobStore(engine, settings.max_attempts, settings.model_ttl_days * 86400)
        registry = WorkerRegistry(engine)
        storage = Storage.for_settings(settings)
        storage.check()  # refused credentials or a missing bucket stop the server at once
        return cls(
            settings=settings,
            engine=engine,
            jobs=jobs,
            keys=KeyStore(engine),
            workers=registry,
            storage=storage,
            dispatch=make_dispatcher(settings),
            renders=RenderDispatcher(registry),
            render_limit=RateLimiter(settings.renders_per_second, 2 * settings.renders_per_second),
            metrics=ServiceMetrics(jobs, registry),
        )

    async def close(self) -> None:
        """Release connections."""
        await self.renders.close()
        self.dispatch.close()
        self.engine.dispose()
