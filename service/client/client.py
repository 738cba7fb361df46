"""``StereoClient``: the three stereo routes of an ADSM service as Python calls returning numpy arrays."""

from __future__ import annotations

import warnings
from collections.abc import Callable, Mapping
from typing import Any, Literal, overload

import httpx
import numpy as np

from service.client import answers
from service.client.answers import DisparityMaps, PointCloud
from service.client.errors import (
    BadRequestError,
    PairWarning,
    RequestTimeoutError,
    ServerBusyError,
    ServerError,
    ServiceError,
    TransportError,
)
from service.client.images import CalibrationInput, ImageInput, calibration_part, image_part
from service.client.retry import RetryPolicy, retry_after_seconds

# Per attempt: connecting is quick or never; the answer may wait behind the service's queue (a few
# inferences of up to a few seconds each at 1080p on a small CPU).
DEFAULT_TIMEOUT = httpx.Timeout(120.0, connect=10.0)


class StereoClient:
    """A client of the service at ``url`` (``http://host:8000``; a path prefix behind a proxy is kept).

    Options of the stereo routes (``max_disparity``, ``lr_check``, ``fill``, ``subpixel``, ``p1``, ...;
    docs/service.md) are keyword arguments, sent as query parameters; the service checks them and a bad
    one raises :class:`~service.client.BadRequestError` with the service's sentence. A 503 is retried by
    ``retry`` (:class:`RetryPolicy`); ``timeout`` (seconds or an ``httpx.Timeout``) bounds each attempt.
    ``transport`` replaces the network (``httpx.MockTransport``, or an app in-process).

    ``calib`` (a calibration file: a path or its bytes; Middlebury ``calib.txt``, KITTI, OpenCV
    .yml/.xml/.json) is sent as the ``calib`` field: instead of ``focal_px``/``baseline_m`` for depth and
    point clouds, and a raw rig's pair is rectified by the service before matching. When the service
    finds the pair suspect (swapped, not rectified, few pixels passing the check) each of its
    ``X-ADSM-Warning`` headers is issued as a :class:`~service.client.PairWarning`.
    """

    def __init__(self, url: str, *, timeout: float | httpx.Timeout = DEFAULT_TIMEOUT,
                 retry: RetryPolicy | None = None, transport: httpx.BaseTransport | None = None,
                 headers: Mapping[str, str] | None = None) -> None:
        self.url = url.rstrip("/")
        self.retry = RetryPolicy() if retry is None else retry
        self._http = httpx.Client(base_url=self.url + "/", timeout=timeout, transport=transport,
                                  headers=headers)

    def __enter__(self) -> StereoClient:
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()

    def close(self) -> None:
        self._http.close()

    @overload
    def disparity(self, left: ImageInput, right: ImageInput, *, format: str = ...,
                  validity: Literal[False] = False, confidence: Literal[False] = False,
                  calib: CalibrationInput | None = ..., **options: Any) -> np.ndarray: ...

    @overload
    def disparity(self, left: ImageInput, right: ImageInput, *, format: str = ..., validity: bool = ...,
                  confidence: bool = ..., calib: CalibrationInput | None = ...,
                  **options: Any) -> DisparityMaps: ...

    def disparity(self, left: ImageInput, right: ImageInput, *, format: str = "npy", validity: bool = False,
                  confidence: bool = False, calib: CalibrationInput | None = None,
                  **options: Any) -> np.ndarray | DisparityMaps:
        """Disparity in pixels, float32 H x W, NaN invalid. With ``validity`` and/or ``confidence``: a
        :class:`DisparityMaps` holding those maps too.

        ``format`` is how the map travels (all decode to the same array): ``npy`` (exact), ``png16``
        (1/256 px steps, smaller) or ``pfm``.
        """
        _check_choice("format", format, answers.DISPARITY_FORMATS)
        params = {**options, "format": format}
        if validity:
            params["validity"] = True
        if confidence:
            params["confidence"] = True
        response = self._post("disparity", left, right, params, calib)
        if validity or confidence:
            return answers.disparity_maps(response.content, response.headers.get("content-type", ""),
                                          validity=validity, confidence=confidence)
        return answers.disparity_map(response.content)

    def depth(self, left: ImageInput, right: ImageInput, *, focal_px: float | None = None,
              baseline_m: float | None = None, calib: CalibrationInput | None = None, format: str = "npy",
              **options: Any) -> np.ndarray:
        """Depth ``z = baseline x focal / (disparity + doffs)`` in metres, float32 H x W, NaN where there is
        none; the camera by ``focal_px`` and ``baseline_m`` (and ``doffs``) or by ``calib``.
        ``format``: ``npy`` (exact) or ``png16`` (whole millimetres; none beyond 65.535 m)."""
        _check_choice("format", format, answers.DEPTH_FORMATS)
        params = {**options, **_camera(focal_px, baseline_m, calib), "format": format}
        return answers.depth_map(self._post("depth", left, right, params, calib).content)

    def pointcloud(self, left: ImageInput, right: ImageInput, *, focal_px: float | None = None,
                   baseline_m: float | None = None, calib: CalibrationInput | None = None,
                   cx: float | None = None, cy: float | None = None, **options: Any) -> PointCloud:
        """Coloured points of every pixel with a depth (``cx``, ``cy`` default to the image centre; a
        ``calib`` file gives all four)."""
        params = {**options, **_camera(focal_px, baseline_m, calib), "cx": cx, "cy": cy}
        return answers.point_cloud(self._post("pointcloud", left, right, params, calib).content)

    def model(self) -> dict[str, Any]:
        """The served model's manifest (``/v1/model``)."""
        return self._send(lambda: self._http.get("v1/model")).json()

    def card(self) -> str:
        """The served model's card, Markdown (``/v1/model/card``): intended use, training data, metrics."""
        return self._send(lambda: self._http.get("v1/model/card")).text

    def ready(self) -> bool:
        """True once the service has loaded and warmed its model (``/readyz`` answers 200)."""
        try:
            return self._http.get("readyz").status_code == 200
        except httpx.TransportError:
            return False

    def _post(self, route: str, left: ImageInput, right: ImageInput, params: Mapping[str, Any],
              calib: CalibrationInput | None = None) -> httpx.Response:
        files = {"left": image_part(left, "left"), "right": image_part(right, "right")}
        if calib is not None:
            files["calib"] = calibration_part(calib)
        query = _query(params)
        response = self._send(lambda: self._http.post(route, params=query, files=files))
        for warning in response.headers.get_list("x-adsm-warning"):
            warnings.warn(PairWarning(warning), stacklevel=3)  # at the caller of disparity/depth/...
        return response

    def _send(self, request: Callable[[], httpx.Response]) -> httpx.Response:
        waited, attempt = 0.0, 1
        while True:
            try:
                response = request()
            except httpx.TimeoutException as error:
                raise RequestTimeoutError(f"no answer from {self.url} in time ({error or 'timeout'}); "
                                          "pass a larger timeout= or send smaller images") from error
            except httpx.TransportError as error:
                raise TransportError(f"cannot talk to {self.url}: {error or type(error).__name__}") from error
            if response.status_code != 503:
                return _checked(response)
            retry_after = retry_after_seconds(response.headers.get("retry-after"))
            delay = self.retry.delay(attempt, retry_after, waited)
            if delay is None:
                raise ServerBusyError(503, _detail(response), request_id=response.headers.get("x-request-id"),
                                      retry_after=retry_after, attempts=attempt)
            self.retry.sleep(delay)
            waited += delay
            attempt += 1


def _checked(response: httpx.Response) -> httpx.Response:
    if response.status_code < 400:
        return response
    kind: type[ServiceError] = BadRequestError if response.status_code < 500 else ServerError
    errors = _json(response).get("errors")
    raise kind(response.status_code, _detail(response), request_id=response.headers.get("x-request-id"),
               errors=errors if isinstance(errors, list) else None)


def _detail(response: httpx.Response) -> str:
    detail = _json(response).get("detail")
    if isinstance(detail, str):
        return detail
    return response.text[:300] or response.reason_phrase or "no detail"


def _json(response: httpx.Response) -> dict[str, Any]:
    try:
        body = response.json()
    except ValueError:
        return {}
    return body if isinstance(body, dict) else {}


def _query(params: Mapping[str, Any]) -> dict[str, str]:
    """Query parameters as the service parses them: booleans ``true``/``false``, None left out."""
    query = {}
    for name, value in params.items():
        if value is None:
            continue
        if isinstance(value, bool | np.bool_):
            query[name] = "true" if value else "false"
        elif isinstance(value, int | float | str | np.integer | np.floating):
            query[name] = str(value)
        else:
            raise TypeError(f"option {name}: expected a number, a string or a boolean, "
                            f"got {type(value).__name__}")
    return query


def _camera(focal_px: float | None, baseline_m: float | None,
            calib: CalibrationInput | None) -> dict[str, Any]:
    """The camera's query parameters; a camera given twice, half or not at all is refused before sending."""
    by_hand = (focal_px is not None, baseline_m is not None)
    if by_hand[0] != by_hand[1]:
        raise ValueError("give focal_px and baseline_m together (or a calib file instead)")
    if all(by_hand) == (calib is not None):
        raise ValueError("give either focal_px and baseline_m, or calib (a calibration file), not "
                         + ("both" if calib is not None else "neither"))
    return {"focal_px": focal_px, "baseline_m": baseline_m}


def _check_choice(name: str, value: str, choices: tuple[str, ...]) -> None:
    if value not in choices:
        raise ValueError(f"{name} must be one of {', '.join(choices)}, got {value!r}")
