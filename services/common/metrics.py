"""Prometheus metrics of the API and the workers (prometheus-client), and how a process exposes them.

One process: the default registry. Several processes sharing one set of numbers (`graspgen serve --workers N`, the
prefork children of `graspgen worker`): prometheus-client's multiprocess mode, switched on by `PROMETHEUS_MULTIPROC_DIR`
before this module is imported (services/cli.py does that); every process then writes its values to files there and
a scrape adds them up.

Labels are bounded: routes by their template (`/v1/jobs/{job_id}`), never the raw path; job kinds and states and core
stages are fixed sets.
"""

from __future__ import annotations

import logging
import os
from collections.abc import Callable, Iterable

from prometheus_client import (
    CONTENT_TYPE_LATEST,
    REGISTRY,
    CollectorRegistry,
    Counter,
    Gauge,
    Histogram,
    generate_latest,
    multiprocess,
)
from prometheus_client.core import GaugeMetricFamily
from prometheus_client.registry import Collector

__all__ = [
    "CONTENT_TYPE_LATEST",
    "HTTP_DURATION",
    "JOBS_FINISHED",
    "JOB_DURATION",
    "STAGE_DURATION",
    "EXPORT_CACHE",
    "PREVIEWS",
    "PREVIEW_DURATION",
    "RATE_LIMITED",
    "QueueDepthCollector",
    "multiprocess_dir",
    "render",
    "scrape_registry",
    "start_metrics_server",
]

log = logging.getLogger(__name__)

#: catalogue lookups answer in a few ms; previews and jobs take seconds
_LATENCY_BUCKETS = (0.001, 0.0025, 0.005, 0.01, 0.025, 0.05, 0.1, 0.25, 0.5, 1.0, 2.5, 5.0, 10.0, 30.0, 60.0)
_JOB_BUCKETS = (0.1, 0.5, 1.0, 2.0, 5.0, 10.0, 30.0, 60.0, 120.0, 300.0, 600.0, 900.0, 1800.0)

HTTP_DURATION = Histogram(
    "graspgen_http_request_duration_seconds",
    "HTTP requests of the API by method, route template and status, from the first byte in to the last byte out",
    ["method", "route", "status"],
    buckets=_LATENCY_BUCKETS,
)
JOBS_FINISHED = Counter(
    "graspgen_jobs_finished_total",
    "Jobs that reached a final state, by kind and state (counted by the process that wrote the state)",
    ["kind", "state"],
)
JOB_DURATION = Histogram(
    "graspgen_job_duration_seconds",
    "Time from a job's creation to its final state, by kind and state",
    ["kind", "state"],
    buckets=_JOB_BUCKETS,
)
STAGE_DURATION = Histogram(
    "graspgen_job_stage_duration_seconds",
    "Wall time of each stage of a job run (load, sample, pairs, collision, cluster, validate, export)",
    ["kind", "stage"],
    buckets=_JOB_BUCKETS,
)
EXPORT_CACHE = Counter(
    "graspgen_export_cache_requests_total",
    "Grasp-set export reads (catalogue lookups, grasp-set reads) served from the API's memory (hit) or storage (miss)",
    ["result"],
)
PREVIEWS = Counter(
    "graspgen_previews_total",
    "preview.png requests by outcome: cached, rendered, rejected (render queue full, 503), failed",
    ["outcome"],
)
PREVIEW_DURATION = Histogram(
    "graspgen_preview_render_seconds",
    "Time to render one preview (off the request path, in the bounded render pool)",
    buckets=_LATENCY_BUCKETS,
)
RATE_LIMITED = Counter("graspgen_rate_limited_total", "Requests answered 429 by the per-token rate limit")
PREVIEWS_IN_FLIGHT = Gauge(
    "graspgen_previews_in_flight",
    "Previews being rendered or waiting for the render pool",
    multiprocess_mode="livesum",
)


def multiprocess_dir() -> str | None:
    return os.environ.get("PROMETHEUS_MULTIPROC_DIR") or None


class QueueDepthCollector(Collector):
    """`graspgen_queue_depth`: jobs waiting for a worker, read when scraped.

    With a broker, the length of the Celery queue's Redis list(s) (kombu keeps one list per priority step, under the
    broker's key prefix); in the embedded mode, the in-process pool's pending jobs.
    """

    def __init__(self, read: Callable[[], int | None]) -> None:
        self._read = read

    def collect(self) -> Iterable[GaugeMetricFamily]:
        try:
            value = self._read()
        except Exception as exc:  # a scrape must not fail because the broker is away; the gauge is just missing
            log.warning("queue depth unavailable: %s", type(exc).__name__)
            value = None
        if value is not None:
            g = GaugeMetricFamily("graspgen_queue_depth", "Jobs waiting in the queue for a worker")
            g.add_metric([], float(value))
            yield g


def redis_queue_depth(broker_url: str, queue: str, key_prefix: str) -> Callable[[], int]:
    """A reader of the Celery queue's length in Redis (the base list plus kombu's priority lists)."""
    import redis

    client = redis.Redis.from_url(broker_url, socket_timeout=2, socket_connect_timeout=2)
    # kombu's Redis transport: priority 0 is the queue's own key, the others `queue\x06\x16<priority>`
    keys = [f"{key_prefix}{queue}"] + [f"{key_prefix}{queue}\x06\x16{p}" for p in (3, 6, 9)]

    def read() -> int:
        pipe = client.pipeline(transaction=False)
        for k in keys:
            pipe.llen(k)
        return int(sum(pipe.execute()))

    return read


def scrape_registry(extra: Iterable[Collector] = ()) -> CollectorRegistry:
    """The registry a scrape reads: this process's metrics, or every process's in multiprocess mode; plus `extra`."""
    if multiprocess_dir():
        registry = CollectorRegistry()
        multiprocess.MultiProcessCollector(registry)
    else:
        registry = CollectorRegistry()
        registry.register(_Forward(REGISTRY))
    for c in extra:
        registry.register(c)
    return registry


class _Forward(Collector):
    """The default registry's metrics inside another registry (which can then carry extra collectors)."""

    def __init__(self, source: CollectorRegistry) -> None:
        self._source = source

    def collect(self) -> Iterable:
        return self._source.collect()


def render(registry: CollectorRegistry) -> bytes:
    return generate_latest(registry)


def start_metrics_server(port: int, host: str, registry: CollectorRegistry) -> None:
    """An unauthenticated plain-HTTP `/metrics` listener in a daemon thread (for a Prometheus on a private network)."""
    from prometheus_client import start_http_server

    start_http_server(port, addr=host, registry=registry)
    log.info("metrics on http://%s:%d/metrics", host, port)
