"""Prometheus metrics: queue depth, jobs by state, workers, render latency."""

from __future__ import annotations

from collections.abc import Iterator

from prometheus_client import CollectorRegistry, Histogram, generate_latest
from prometheus_client.core import GaugeMetricFamily
from prometheus_client.registry import Collector

from sparsesplat.api.store.jobs import JobStore
from sparsesplat.api.store.workers import WorkerRegistry


class _StoreCollector(Collector):
    """Reads job counts and live workers from the database at scrape time."""

    def __init__(self, jobs: JobStore, workers: WorkerRegistry) -> None:
        self.jobs = jobs
        self.workers = workers

    def collect(self) -> Iterator[GaugeMetricFamily]:
        counts = self.jobs.counts_by_state()
        by_state = GaugeMetricFamily("sparsesplat_jobs", "Jobs by state", labels=["state"])
        for state, n in counts.items():
            by_state.add_metric([state], n)
        yield by_state
        yield GaugeMetricFamily(
            "sparsesplat_queue_depth", "Jobs waiting for a worker", value=counts.get("queued", 0)
        )
        live = GaugeMetricFamily("sparsesplat_workers", "Workers with a fresh heartbeat",
                                 labels=["kind"])  # fmt: skip
        workers = self.workers.live()
        for kind in ("train", "render"):
            live.add_metric([kind], sum(w.kind == kind for w in workers))
        yield live


class ServiceMetrics:
    """One application's metrics (own registry: several apps in one process stay apart)."""

    def __init__(self, jobs: JobStore, workers: WorkerRegistry) -> None:
        """Metrics over ``jobs`` and ``workers``."""
        self.registry = CollectorRegistry()
        self.registry.register(_StoreCollector(jobs, workers))
        self.render_seconds = Histogram(
            "sparsesplat_render_seconds",
            "Render request latency in the API, encoding included",
            buckets=(0.025, 0.05, 0.1, 0.2, 0.5, 1, 2, 5, 10, 30),
            registry=self.registry,
        )

    def exposition(self) -> bytes:
        """The text format Prometheus scrapes."""
        return generate_latest(self.registry)
