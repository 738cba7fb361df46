"""ASGI middleware of the HTTP service, each guarding one thing for every request, whatever the route.

``delivery`` (answers leave in bounded pieces within a deadline), ``request_id`` (an X-Request-ID on
every response), ``metrics`` (requests and latency by route), ``framing`` (ambiguous body length
refused), ``body_size`` (413 past the byte limit) and ``body_timeout`` (408 past the body deadline), the
last two sharing ``body_guard``. ``service/api/app.py`` installs them in that order, outermost first.
"""
