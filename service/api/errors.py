"""Error responses: always JSON ``{"detail": "..."}``, and one status rule for bad input.

The rule (documented in the OpenAPI schema and docs/service.md):

- 400: anything wrong with the request itself: a query parameter of the wrong type or out of range,
  a missing multipart field, malformed multipart, images of different sizes, a disparity range the
  image cannot hold, a camera given twice or not at all, a calibration file that cannot be used.
  FastAPI's own 422 for request validation is folded into 400 so that a client has one code to handle;
  ``errors`` then lists each problem with its location.
- 408: the body did not arrive in full within ``ADSM_BODY_TIMEOUT_S`` (a stalled or trickled upload).
- 413: body over the byte limit, an image over the pixel limit (checked before decoding), or a job
  whose cost volume (width x height x disparities) is over the cell limit, whose memory plan is over
  the per-request byte limit or whose tower work is over its limit (service/memory.py), all from the
  image headers.
- 415: a part that is not a decodable image.
- 503 + Retry-After: the inference queue is full, or the model is still warming up.

The service object raises domain errors (service/api/refusals.py, the queue's, the runtime's), never
HTTP ones; :data:`STATUS_OF` is the one table that turns each into its status code.
"""

from __future__ import annotations

from typing import Any, cast

from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.openapi.utils import get_openapi
from fastapi.responses import JSONResponse
from pydantic import BaseModel

from service.api.refusals import BadRequest, ClientGone, Unavailable
from service.calibration import CalibrationError
from service.io import ImageDecodeError, ImageTooLargeError
from service.limits import DisparityRangeError, LimitError

# Domain error -> status. A subclass not listed takes its nearest listed ancestor's status (the handlers
# are looked up along the class's MRO), so ImageTooLargeError is 413 although it is an ImageDecodeError.
STATUS_OF: dict[type[Exception], int] = {
    BadRequest: 400,            # malformed multipart, images of different sizes, options refused
    CalibrationError: 400,      # a calib file that cannot be read or does not fit the images
    DisparityRangeError: 400,   # a range this image or this server's ADSM_MAX_DISPARITY cannot take
    LimitError: 413,            # cost-volume cells, memory plan, tower work
    ImageTooLargeError: 413,    # pixels, read from the header before decoding
    ImageDecodeError: 415,      # a part that is not a decodable image
    ClientGone: 499,            # nginx's "client closed request" (queue.ClientDisconnected too)
    Unavailable: 503,           # not ready, draining, answers backlogged, queue.QueueFull: + Retry-After
}


class ErrorBody(BaseModel):
    detail: str


_DESCRIPTIONS = {
    400: "Bad parameters, missing or malformed multipart fields, images of different sizes, or a calibration "
    "file that cannot be read or does not fit the images.",
    408: "The request body did not arrive in full within ADSM_BODY_TIMEOUT_S seconds.",
    413: "Request body over ADSM_MAX_BODY_BYTES, an image over ADSM_MAX_PIXELS, a cost volume "
    "(width x height x disparities) over ADSM_MAX_COST_CELLS, a memory plan over ADSM_MAX_REQUEST_BYTES, "
    "or an image so elongated that its feature towers would compute over twice a square image's work.",
    415: "A multipart part is not a decodable image (PNG, JPEG, PPM/PGM, TIFF, ...).",
    503: "The inference queue is full or the model is warming up; retry after `Retry-After` seconds.",
}


def error_responses(*codes: int) -> dict[int | str, dict[str, Any]]:
    """OpenAPI ``responses`` entries for the given error codes."""
    return {code: {"model": ErrorBody, "description": _DESCRIPTIONS[code]} for code in codes}


def _location(loc: tuple[Any, ...]) -> str:
    return ".".join(str(part) for part in loc)


async def validation_error_handler(request: Request, error: Exception) -> JSONResponse:
    error = cast(RequestValidationError, error)  # the one class it is installed for
    problems = [
        {"loc": [str(part) for part in problem["loc"]], "msg": problem["msg"], "type": problem["type"]}
        for problem in error.errors()
    ]
    detail = "; ".join(f"{_location(problem['loc'])}: {problem['msg']}" for problem in error.errors())
    return JSONResponse({"detail": detail or "invalid request", "errors": problems}, status_code=400)


def status_of(error: BaseException) -> int | None:
    """The status :data:`STATUS_OF` gives ``error`` (its nearest listed class), None for any other error."""
    return next((STATUS_OF[kind] for kind in type(error).__mro__ if kind in STATUS_OF), None)


def domain_error_response(error: Exception) -> JSONResponse:
    """The answer to a domain error: its message as ``detail``, its status, and for an Unavailable the
    Retry-After (and Connection: close when the process is leaving)."""
    headers = None
    if isinstance(error, Unavailable):
        headers = {"Retry-After": str(error.retry_after)}
        if error.close_connection:
            headers["Connection"] = "close"
    status = status_of(error)
    if status is None:
        raise TypeError(f"{type(error).__name__} has no status in STATUS_OF") from error
    return JSONResponse({"detail": str(error)}, status_code=status, headers=headers)


async def domain_error_handler(request: Request, error: Exception) -> JSONResponse:
    return domain_error_response(error)


def install_error_handlers(app: FastAPI) -> None:
    app.add_exception_handler(RequestValidationError, validation_error_handler)
    for kind in STATUS_OF:
        app.add_exception_handler(kind, domain_error_handler)
    app.openapi = lambda: _openapi_without_422(app)  # type: ignore[method-assign]


def _openapi_without_422(app: FastAPI) -> dict[str, Any]:
    """The generated schema, minus FastAPI's automatic 422 entries (the service answers 400 instead)."""
    if app.openapi_schema is None:
        schema = get_openapi(
            title=app.title, version=app.version, description=app.description, routes=app.routes
        )
        for path in schema.get("paths", {}).values():
            for operation in path.values():
                operation.get("responses", {}).pop("422", None)
        schemas = schema.get("components", {}).get("schemas", {})
        for unused in ("HTTPValidationError", "ValidationError"):
            schemas.pop(unused, None)
        app.openapi_schema = schema
    return app.openapi_schema
