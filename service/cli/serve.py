"""`adsm serve`: run the HTTP service (uvicorn) on the default or a given model folder.

Options become the ``ADSM_*`` environment variables the app reads, so that every worker process
(``--workers N`` starts N processes, each with its own model and queue) sees the same settings.
"""

from __future__ import annotations

import argparse
import os
import sys

_APP_FACTORY = "service.api.app:create_app"


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "serve",
        help="run the HTTP service",
        description="Serve POST /disparity, /depth, /pointcloud, a demo page at / and the OpenAPI docs at "
        "/docs. Other settings come from ADSM_* environment variables (see docs/service.md).",
    )
    parser.add_argument("--host", default="127.0.0.1", help="interface to bind (default 127.0.0.1; "
                        "0.0.0.0 for every interface)")
    parser.add_argument("--port", type=int, default=8000, help="TCP port (default 8000)")
    parser.add_argument("--model", metavar="DIR", help="model folder (default: $ADSM_MODEL_DIR or the "
                        "shipped default model)")
    parser.add_argument("--workers", type=int, default=1, metavar="N",
                        help="worker processes, each with its own model and queue (default 1)")
    parser.add_argument("--threads", type=int, metavar="N", help="compute threads per worker (default: "
                        "$ADSM_THREADS, else the cores divided among the workers)")
    parser.add_argument(
        "--log-level", default="info", choices=("critical", "error", "warning", "info", "debug")
    )
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    import uvicorn

    from service.api.settings import Settings
    from service.features import ModelError, default_model_dir, load_manifest

    if args.workers < 1:
        raise ValueError(f"--workers must be >= 1, got {args.workers}")
    if not 0 < args.port < 65536:
        raise ValueError(f"--port must be in 1..65535, got {args.port}")
    if args.model:
        os.environ["ADSM_MODEL_DIR"] = os.path.abspath(args.model)
    if args.threads is not None:
        os.environ["ADSM_THREADS"] = str(args.threads)
    elif not os.environ.get("ADSM_THREADS") and args.workers > 1:
        # N workers each using every core would only fight over them.
        os.environ["ADSM_THREADS"] = str(max(1, (os.cpu_count() or 1) // args.workers))
    settings = Settings.from_env()  # fail here, with one line, on a malformed variable
    try:
        load_manifest(settings.model_dir or default_model_dir())  # hashes are verified at start-up
    except ModelError as error:
        print(f"adsm: error: {error}", file=sys.stderr)
        return 1
    uvicorn.run(
        _APP_FACTORY,
        factory=True,
        host=args.host,
        port=args.port,
        workers=args.workers,
        log_level=args.log_level,
        timeout_graceful_shutdown=30,
    )
    return 0
