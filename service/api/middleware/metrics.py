"""Count and time every HTTP response into :class:`~service.api.metrics.ServiceMetrics`.

Labels never carry request data: the route is the matched path template, never the raw path, and the
method is one of HTTP's own (RFC 9110), any other token a client sends being counted as ``other`` (each
new label set is a series kept for the process's life: a client inventing methods, each up to the request
line's length, made /metrics grow without bound).
"""

from __future__ import annotations

import time

from starlette.types import ASGIApp, Message, Receive, Scope, Send

from service.api.metrics import ServiceMetrics

# RFC 9110 section 9 and PATCH (RFC 5789): the methods a label may name.
METHODS = frozenset({"GET", "HEAD", "POST", "PUT", "DELETE", "CONNECT", "OPTIONS", "TRACE", "PATCH"})


class MetricsMiddleware:
    """Count and time every HTTP response, labelled by the matched route template."""

    def __init__(self, app: ASGIApp, *, metrics: ServiceMetrics) -> None:
        self.app = app
        self.metrics = metrics

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        started = time.perf_counter()
        status = 500  # an exception before the response started ends as a 500

        async def status_send(message: Message) -> None:
            nonlocal status
            if message["type"] == "http.response.start":
                status = message["status"]
            await send(message)

        try:
            await self.app(scope, receive, status_send)
        finally:
            route = scope.get("route")
            labels = {
                "method": scope["method"] if scope["method"] in METHODS else "other",
                "route": getattr(route, "path", None) or "unmatched",
                "status": str(status),
            }
            self.metrics.requests.labels(**labels).inc()
            self.metrics.latency.labels(**labels).observe(time.perf_counter() - started)
