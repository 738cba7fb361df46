"""Prometheus metrics: requests and latency by route and status, stage timings, queue depth, rejections.

:class:`ServiceMetrics` holds them; the middleware that counts and times every response is
``service/api/middleware/metrics.py``.

prometheus-client (pure Python, no dependencies) writes the text exposition format, whose escaping
and histogram conventions (cumulative ``le`` buckets, ``_sum``, ``_count``) are easy to get subtly
wrong by hand. Each app owns its registry, so several apps in one process (tests) do not collide.
Labels never carry request data: the route is the path template, never the raw path.
"""

from __future__ import annotations

from prometheus_client import (
    CollectorRegistry,
    Counter,
    Gauge,
    Histogram,
    disable_created_metrics,
    generate_latest,
)
from prometheus_client.exposition import CONTENT_TYPE_LATEST

from service.api.queue import InferenceSlot

CONTENT_TYPE = CONTENT_TYPE_LATEST
# The *_created series (one timestamp per label set) double the exposition for no dashboard use.
disable_created_metrics()

# Inference on a laptop-size pair takes 0.1-10 s; health checks take microseconds.
_LATENCY_BUCKETS = (0.001, 0.005, 0.025, 0.1, 0.25, 0.5, 1.0, 2.5, 5.0, 10.0, 30.0, 60.0)


class ServiceMetrics:
    def __init__(self, slot: InferenceSlot) -> None:
        self.registry = CollectorRegistry()
        self.requests = Counter(
            "adsm_http_requests", "HTTP requests answered.", ("method", "route", "status"),
            registry=self.registry,
        )
        self.latency = Histogram(
            "adsm_http_request_duration_seconds", "Time from request start to the end of the response.",
            ("method", "route", "status"), buckets=_LATENCY_BUCKETS, registry=self.registry,
        )
        self.stages = Histogram(
            "adsm_stage_duration_seconds",
            "Seconds per pipeline stage (decode, queue, towers, cost_volume, sgm, disparity, encode, ...).",
            ("stage",), buckets=_LATENCY_BUCKETS, registry=self.registry,
        )
        self.rejections = Counter(
            "adsm_queue_rejections", "Requests turned away with 503 because the queue was full.",
            registry=self.registry,
        )
        waiting = Gauge("adsm_queue_waiting", "Requests admitted and waiting for the inference slot.",
                        registry=self.registry)
        waiting.set_function(lambda: slot.waiting)
        running = Gauge("adsm_inference_running", "1 while an inference runs.", registry=self.registry)
        running.set_function(lambda: int(slot.running))
        self.unsent = Gauge("adsm_unsent_answer_bytes", "Answer bytes not yet taken by slow clients.",
                            registry=self.registry)
        self.ready = Gauge("adsm_ready", "1 once the model is loaded and warmed.", registry=self.registry)
        self.model = Gauge("adsm_model_info", "The model being served (value 1).", ("name",),
                           registry=self.registry)

    def observe_stages(self, timings: dict[str, float]) -> None:
        for stage, seconds in timings.items():
            self.stages.labels(stage=stage).observe(seconds)

    def exposition(self) -> bytes:
        return generate_latest(self.registry)

