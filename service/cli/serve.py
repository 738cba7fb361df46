"""`adsm serve`: run the HTTP service (uvicorn) on the default or a given model folder.

Options become the ``ADSM_*`` environment variables the app reads, so that every worker process
(``--workers N`` starts N processes, each with its own model and queue) sees the same settings.
``--host`` and ``--port`` default to ``$ADSM_HOST`` and ``$ADSM_PORT``, which the image sets.
"""

from __future__ import annotations

import argparse
import logging
import os
import sys
from typing import TYPE_CHECKING

from service.cuda import DEVICE_HELP, DEVICES

if TYPE_CHECKING:  # imported when serving only: `adsm predict` must not pay for FastAPI
    from service.api.settings import Settings

_APP_FACTORY = "service.api.app:create_app"

logger = logging.getLogger("adsm")


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "serve",
        help="run the HTTP service",
        description="Serve POST /disparity, /depth, /pointcloud, a demo page at / and the OpenAPI docs at "
        "/docs. Other settings come from ADSM_* environment variables (see docs/service.md).",
    )
    parser.add_argument(
        "--host", help="interface to bind (default: $ADSM_HOST, else 127.0.0.1; 0.0.0.0 for all)"
    )
    parser.add_argument("--port", type=int, help="TCP port (default: $ADSM_PORT, else 8000)")
    parser.add_argument("--model", metavar="DIR", help="model folder (default: $ADSM_MODEL_DIR or the "
                        "shipped default model)")
    parser.add_argument("--workers", type=int, default=1, metavar="N",
                        help="worker processes, each with its own model and queue (default 1)")
    parser.add_argument("--threads", type=int, metavar="N", help="compute threads per worker (default: "
                        "$ADSM_THREADS, else the cores divided among the workers)")
    parser.add_argument("--device", choices=DEVICES, help=DEVICE_HELP)
    parser.add_argument(
        "--log-level", default="info", choices=("critical", "error", "warning", "info", "debug")
    )
    parser.set_defaults(func=run)


def _env_port() -> int:
    raw = os.environ.get("ADSM_PORT") or "8000"
    try:
        return int(raw)
    except ValueError:
        raise ValueError(f"ADSM_PORT must be an integer, got {raw!r}") from None


def _check_model(settings: Settings) -> str | None:
    """Load the model folder and warm it up once, before the port opens: a warm-up failure in one line, or
    None; a folder that cannot load raises ModelError, which ``adsm`` reports as every command does.

    Hashes and schema (load), the towers against the manifest's channels and receptive field, then the
    whole pipeline on a tiny pair (Matcher.warmup): a folder that cannot serve, e.g. a hand-edited
    manifest, stops the start here instead of opening a port that answers 503. The kernels it compiles
    stay compiled in this process, and in the cache for every worker, so the app's own warm-up is short.
    """
    from service.features import ModelError
    from service.matcher import Matcher

    try:
        Matcher.from_folder(settings.model_dir, threads=settings.threads, device=settings.device).warmup()
    except ModelError:
        raise  # a bad folder is reported like every command's (service/cli/__init__.py)
    except Exception as error:  # any warm-up failure: the same one line, never a traceback
        logger.debug("warm-up failed", exc_info=True)
        return " ".join(f"model warm-up failed: {type(error).__name__}: {error}".split())
    return None


def run(args: argparse.Namespace) -> int:
    import uvicorn

    from service.api.settings import Settings

    host = args.host or os.environ.get("ADSM_HOST") or "127.0.0.1"
    port = _env_port() if args.port is None else args.port
    if args.workers < 1:
        raise ValueError(f"--workers must be >= 1, got {args.workers}")
    if not 0 < port < 65536:
        raise ValueError(f"--port must be in 1..65535, got {port}")
    if args.model:
        os.environ["ADSM_MODEL_DIR"] = os.path.abspath(args.model)
    if args.device is not None:
        os.environ["ADSM_DEVICE"] = args.device
    if args.threads is not None:
        os.environ["ADSM_THREADS"] = str(args.threads)
    elif not os.environ.get("ADSM_THREADS") and args.workers > 1:
        # N workers each using every core would only fight over them.
        os.environ["ADSM_THREADS"] = str(max(1, (os.cpu_count() or 1) // args.workers))
    settings = Settings.from_env()  # fail here, with one line, on a malformed variable
    if problem := _check_model(settings):
        print(f"adsm: error: {problem}", file=sys.stderr)
        return 1
    uvicorn.run(
        _APP_FACTORY,
        factory=True,
        host=host,
        port=port,
        workers=args.workers,
        log_level=args.log_level,
        timeout_graceful_shutdown=30,
    )
    return 0
