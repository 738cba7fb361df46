"""The service's one matcher: loading, warm-up, and the request pipeline shared by every stereo route.

Pipeline of a stereo request: admission (QueueFull at once when the queue is full) -> multipart body (408
when it takes longer than ADSM_BODY_TIMEOUT_S, service/api/middleware/body_timeout.py) -> both image
headers: sizes, pixel limit, then the request's memory plan (service/memory.py) against ADSM_MAX_REQUEST_BYTES
and its tower work against ADSM_MAX_PIXELS, all before a pixel is decoded -> the camera (query numbers
or the ``calib`` file, service/api/camera.py) -> decode both images in a thread (and rectify them when
the calibration describes a raw rig) -> wait for the inference slot -> match, then the pair diagnostics
(service/api/pair_warnings.py), in a thread -> the route encodes. Each step's seconds go into the
Server-Timing header and the per-stage histogram.

A refused request raises a domain error, never an HTTP one: this module's and the queue's
(service/api/refusals.py), the runtime's (DisparityRangeError, LimitError, ImageDecodeError,
ImageTooLargeError); service/api/errors.py maps each to its status code and headers.
"""

from __future__ import annotations

import dataclasses
import logging
import time
from typing import Any

import numpy as np
from fastapi import Request
from starlette.concurrency import run_in_threadpool
from starlette.datastructures import UploadFile
from starlette.requests import ClientDisconnect

from service import jit
from service.api.camera import CALIBRATION_FIELD, CalibrationFile, CameraRequest
from service.api.metrics import ServiceMetrics
from service.api.middleware.delivery import Unsent
from service.api.pair_warnings import match_and_check
from service.api.queue import InferenceSlot, QueueFull
from service.api.refusals import (
    WARMING_RETRY_AFTER_S,
    Backlogged,
    BadRequest,
    ClientGone,
    Draining,
    NotReady,
)
from service.api.settings import Settings
from service.calibration import StereoCalibration
from service.io import image_size, read_image
from service.limits import RequestLimits, check_plan, check_range_size
from service.matcher import Matcher, MatchOptions, StereoResult
from service.protocols import StereoMatcher

logger = logging.getLogger("service.api")


def warming_headers() -> dict[str, str]:
    """The headers of /readyz's 503 while loading or warming up: a fixed Retry-After."""
    return {"Retry-After": str(WARMING_RETRY_AFTER_S)}


@dataclasses.dataclass(frozen=True)
class StereoMatch:
    result: StereoResult
    left: np.ndarray  # uint8 HxWx3, the colours of the point cloud
    timings: dict[str, float]  # decode, queue, then the matcher's stages
    started: float  # perf_counter() when the request was admitted, for the total
    calibration: StereoCalibration | None = None  # the camera, for the images as matched
    rectified: bool = False  # the pair was rectified with ``calibration`` before matching
    warnings: tuple[str, ...] = ()  # "kind: sentence" of each pair diagnostic (X-ADSM-Warning)


class InferenceService:
    """Owns the matcher and the slot; ``ready`` turns True once the model is loaded and warmed."""

    def __init__(self, settings: Settings, *, matcher: StereoMatcher | None = None) -> None:
        self.settings = settings
        self.limits = RequestLimits(max_pixels=settings.max_pixels, max_disparity=settings.max_disparity,
                                    max_cost_cells=settings.max_cost_cells,
                                    max_request_bytes=settings.max_request_bytes)
        self.slot = InferenceSlot(queue_size=settings.queue_size)
        self.metrics = ServiceMetrics(self.slot)
        self.matcher: StereoMatcher | None = matcher
        self.ready = False
        self.failure: str | None = None
        self.draining = False  # SIGTERM received: admitted requests finish, new ones get 503
        self.unsent = Unsent()  # answer bytes slow clients have not taken yet (middleware/delivery.py)
        self.metrics.unsent.set_function(lambda: self.unsent.bytes)

    @property
    def manifest(self) -> dict[str, Any]:
        return self._loaded().manifest

    def _loaded(self) -> StereoMatcher:
        if self.matcher is None:
            raise NotReady("the model is not loaded yet")
        return self.matcher

    def load(self) -> None:
        """Load the model folder (hashes verified by the towers); raises ModelError for a bad folder."""
        if not jit.is_configured():  # embedded without `adsm serve`: the service starts here
            jit.configure_cache()
        if self.matcher is None:
            self.matcher = Matcher.from_folder(self.settings.model_dir, threads=self.settings.threads,
                                               device=self.settings.device)
        self.metrics.model.labels(name=str(self.matcher.manifest.get("name", "unknown"))).set(1)

    def warm(self) -> None:
        """Compile every kernel and run the towers once, then declare readiness."""
        started = time.perf_counter()
        if self.settings.warmup:
            self._loaded().warmup()
        self.ready = True
        self.metrics.ready.set(1)
        logger.info("model warmed in %.1f s (device %s); ready", time.perf_counter() - started,
                    self.settings.device)

    def start_draining(self) -> None:
        """Turn away new stereo requests and report not ready (see service/api/draining.py)."""
        self.draining = True
        self.metrics.ready.set(0)

    async def match(self, request: Request, options: MatchOptions, *, camera: CameraRequest | None = None,
                    diagnostics: bool = False) -> StereoMatch:
        """Read, check, decode and match one pair. ``camera``: the route takes a camera (a ``calib`` file
        is refused without); ``diagnostics``: look at the pair for signs of a swap or missing
        rectification (StereoMatch.warnings)."""
        if self.draining:
            # Refused before its body was read: take the body first (bounded by the size limit and the body
            # deadline, nothing kept), so that closing the connection after the 503 does not reset it
            # under a client still sending and lose the answer.
            await _discard_body(request)
            raise Draining("the server is shutting down; retry (another instance may answer)")
        if not self.ready:
            raise NotReady("the model is warming up")
        self._check_unsent()
        try:
            admission = self.slot.admit()
        except QueueFull:
            self.metrics.rejections.inc()
            raise
        with admission:
            return await self._match_admitted(request, options, camera, diagnostics, time.perf_counter())

    async def _match_admitted(self, request: Request, options: MatchOptions, camera: CameraRequest | None,
                              diagnostics: bool, admitted: float) -> StereoMatch:
        left_bytes, right_bytes, calib = await _read_pair(request, calib=camera is not None)
        started = time.perf_counter()
        height, width = await run_in_threadpool(self._pair_size, left_bytes, right_bytes)
        calibration = None  # BadRequest, CalibrationError (400): a camera missing, twice, or unusable
        if camera is not None:
            calibration = await run_in_threadpool(camera.resolve, calib, height, width)
        self._check_request(height, width, options)
        left, right = await run_in_threadpool(self._decode_pair, left_bytes, right_bytes)
        timings = {"decode": time.perf_counter() - started}
        del left_bytes, right_bytes
        rectified = calibration is not None and calibration.needs_rectification
        if calibration is not None and rectified:
            from service.calibration.rectify import Rectifier  # OpenCV, imported only when a rig needs it

            started = time.perf_counter()
            left, right = await run_in_threadpool(Rectifier(calibration), left, right)
            timings["rectify"] = time.perf_counter() - started
        self._check_unsent()
        queued = time.perf_counter()
        try:  # a client that leaves while queued ends the request here (ClientGone, raised by the slot)
            began, result, check = await self.slot.run(
                match_and_check, self._loaded(), left, right, options, diagnostics,
                disconnected=request.is_disconnected,
            )
        except ValueError as error:  # the matcher's word on bad options for this pair
            raise BadRequest(str(error)) from None
        timings["queue"] = began - queued
        # The matcher's own "total" is left out: the route reports the whole request's total instead.
        timings.update((stage, seconds) for stage, seconds in result.timings.items() if stage != "total")
        if check is not None:
            timings["check"] = check.seconds
        return StereoMatch(result=result, left=left, timings=timings, started=admitted,
                           calibration=calibration, rectified=rectified,
                           warnings=() if check is None else check.warnings)

    def _check_unsent(self) -> None:
        """Backlogged while slow clients leave more than ADSM_MAX_UNSENT_BYTES of answers untaken: checked
        on admission and again before the inference, so answers made meanwhile stay within the limit."""
        if self.unsent.bytes > self.settings.max_unsent_bytes:
            raise Backlogged(
                f"{self.unsent.bytes} bytes of answers are still waiting for slow clients, over this "
                f"server's limit of {self.settings.max_unsent_bytes} (ADSM_MAX_UNSENT_BYTES); retry"
            )

    def _check_request(self, height: int, width: int, options: MatchOptions) -> None:
        """Every size limit of a request, from the image headers: nothing is allocated before they pass.
        The rules are service/limits.py's, applied to the matcher's own range rule and memory plan;
        DisparityRangeError for a range this server or this image cannot take, LimitError for a request
        over a size limit."""
        check_range_size(options.max_disparity, self.limits)
        plan = self._loaded().plan(height, width, options)
        check_plan(plan, self.manifest, self.limits)

    def _pair_size(self, left_bytes: bytes, right_bytes: bytes) -> tuple[int, int]:
        """The pair's (height, width) from the headers (ImageTooLargeError, ImageDecodeError); BadRequest
        when the two differ."""
        sizes = [image_size(data, max_pixels=self.settings.max_pixels, name=name)
                 for name, data in (("left", left_bytes), ("right", right_bytes))]
        (height, width), (right_height, right_width) = sizes
        if sizes[0] != sizes[1]:
            raise BadRequest(
                f"left and right images differ in size: {width} x {height} vs "
                f"{right_width} x {right_height} (width x height); the pair must be rectified"
            )
        return height, width

    def _decode_pair(self, left_bytes: bytes, right_bytes: bytes) -> tuple[np.ndarray, np.ndarray]:
        left = read_image(left_bytes, max_pixels=self.settings.max_pixels, name="left")
        return left, read_image(right_bytes, max_pixels=self.settings.max_pixels, name="right")


async def _discard_body(request: Request) -> None:
    """Read the request's body to its end and drop it."""
    try:
        async for _ in request.stream():
            pass
    except ClientDisconnect:
        raise ClientGone("client disconnected during the upload") from None


async def _read_pair(request: Request, *, calib: bool) -> tuple[bytes, bytes, CalibrationFile | None]:
    """The bytes of the ``left`` and ``right`` file parts of a multipart/form-data body, and the optional
    ``calib`` file part where the route takes a camera (``calib``)."""
    content_type = request.headers.get("content-type", "")
    # Media types are case-insensitive (RFC 9110 8.3.1); the multipart parser lower-cases them too.
    if not content_type.strip().lower().startswith("multipart/form-data"):
        raise BadRequest(
            f"expected a multipart/form-data body with files 'left' and 'right', got "
            f"{content_type or 'no Content-Type'}"
        )
    allowed = ("left", "right", CALIBRATION_FIELD) if calib else ("left", "right")
    try:
        form = await request.form(max_files=len(allowed), max_fields=16)
    except ClientDisconnect:  # gone mid-upload: nobody to answer, and not a server error
        raise ClientGone("client disconnected during the upload") from None
    try:
        # A misspelt or unexpected part is refused rather than ignored: the client learns of its mistake.
        if unexpected := sorted(set(form.keys()) - set(allowed)):
            optional = f" (and optionally '{CALIBRATION_FIELD}')" if calib else ""
            raise BadRequest(
                f"unexpected multipart field '{unexpected[0]}'; send only the files 'left' and "
                f"'right'{optional}"
            )
        # A part given twice is refused too: one of the two would be used and the other silently ignored.
        if repeated := sorted(name for name in form if len(form.getlist(name)) > 1):
            raise BadRequest(f"multipart field '{repeated[0]}' is given more than once; send it once")
        parts: dict[str, bytes] = {}
        for name in allowed:
            part = form.get(name)
            if part is None:
                if name == CALIBRATION_FIELD:
                    continue
                raise BadRequest(f"multipart field '{name}' is missing (an image file)")
            if not isinstance(part, UploadFile):
                raise BadRequest(f"multipart field '{name}' must be a file, not a text field")
            parts[name] = await part.read()
        upload = form.get(CALIBRATION_FIELD)
        calibration = (CalibrationFile(upload.filename, parts[CALIBRATION_FIELD])
                       if isinstance(upload, UploadFile) else None)
        return parts["left"], parts["right"], calibration
    finally:
        await form.close()
