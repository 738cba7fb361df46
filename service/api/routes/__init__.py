"""The HTTP routes, one module per group: ``stereo`` (POST /disparity, /depth, /pointcloud), ``ops``
(health, readiness, metrics, the model and its card, the demo page), ``docs`` (the offline OpenAPI page).

Each exposes ``router`` for ``service/api/app.py``; ``encoding`` and ``geometry`` are what the stereo
routes use to write their answers. Routes hold no state: they ask the service object
(``service/api/inference.py``) for a match and encode it.
"""
