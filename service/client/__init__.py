"""A Python client of the ADSM stereo service: images in, numpy arrays out.

    from service.client import StereoClient

    with StereoClient("http://localhost:8000") as client:
        disparity = client.disparity("left.png", "right.png", max_disparity=64)   # float32, NaN invalid
        maps = client.disparity(left_array, right_array, validity=True)          # .disparity, .validity
        depth = client.depth("left.png", "right.png", focal_px=700, baseline_m=0.1)  # metres
        cloud = client.pointcloud("left.png", "right.png", focal_px=700, baseline_m=0.1)  # .points, .colors

It needs httpx, NumPy and Pillow only (``pip install 'adsm-stereo[client]'``) and imports none of the
service's runtime (no ONNX Runtime, Numba or FastAPI): a robot or a notebook can use it without them.
"""

from service.client.answers import DisparityMaps, PointCloud
from service.client.client import DEFAULT_TIMEOUT, StereoClient
from service.client.errors import (
    AnswerFormatError,
    BadRequestError,
    PairWarning,
    RequestTimeoutError,
    ServerBusyError,
    ServerError,
    ServiceError,
    StereoClientError,
    TransportError,
)
from service.client.retry import RetryPolicy

__all__ = [
    "DEFAULT_TIMEOUT",
    "AnswerFormatError",
    "BadRequestError",
    "DisparityMaps",
    "PairWarning",
    "PointCloud",
    "RequestTimeoutError",
    "RetryPolicy",
    "ServerBusyError",
    "ServerError",
    "ServiceError",
    "StereoClient",
    "StereoClientError",
    "TransportError",
]
