"""The service's answers as numpy arrays: disparity (png16, npy, pfm), depth (npy, png16), the
multipart/mixed answer of ``validity=true`` (a part per map, picked by name), and binary PLY point clouds.

Every map comes back as the service's Python API gives it: float32, NaN where there is no value.
"""

from __future__ import annotations

import dataclasses
import io
import re

import numpy as np
from PIL import Image

from service.client.errors import AnswerFormatError
from service.io.disparity import decode_disparity

DISPARITY_FORMATS = ("npy", "png16", "pfm")  # lossless ones; "color" is a picture for people
DEPTH_FORMATS = ("npy", "png16")
_MM_PER_M = 1000.0  # /depth's png16 holds millimetres
_PLY_TYPES = {"float": "<f4", "float32": "<f4", "double": "<f8", "float64": "<f8", "uchar": "u1",
              "uint8": "u1", "char": "i1", "int8": "i1", "ushort": "<u2", "uint16": "<u2", "short": "<i2",
              "int16": "<i2", "uint": "<u4", "uint32": "<u4", "int": "<i4", "int32": "<i4"}


@dataclasses.dataclass(frozen=True)
class DisparityMaps:
    """``/disparity`` with extra maps asked for: each is None unless it was asked for."""

    disparity: np.ndarray  # float32 H x W, pixels; NaN invalid
    validity: np.ndarray | None = None  # uint8 H x W codes: 0 valid, 1 occluded, 2 mismatch, 3 no data,
    #                                     5 filled occlusion, 6 filled mismatch
    confidence: np.ndarray | None = None  # float32 H x W in [0, 1]


@dataclasses.dataclass(frozen=True)
class PointCloud:
    """``/pointcloud``: one row per pixel with a depth, in the left camera's frame (x right, y down, z
    forward), metres."""

    points: np.ndarray  # float32 N x 3
    colors: np.ndarray | None  # uint8 N x 3, the left image's RGB (None if the PLY has no colour)

    def __len__(self) -> int:
        return int(self.points.shape[0])


def disparity_map(body: bytes) -> np.ndarray:
    """A png16 / npy / pfm disparity answer (told apart by content) as float32, NaN invalid."""
    try:
        return decode_disparity(body, source="the disparity answer")
    except ValueError as error:
        raise AnswerFormatError(str(error)) from None


def depth_map(body: bytes) -> np.ndarray:
    """An npy (metres) or png16 (millimetres, 0 none) depth answer as float32 metres, NaN where none."""
    try:
        if body.startswith(b"\x93NUMPY"):
            depth = np.load(io.BytesIO(body), allow_pickle=False)
            if depth.ndim != 2 or depth.dtype.kind != "f":
                raise ValueError(f"expected a float H x W array, got {depth.dtype} {depth.shape}")
            return depth.astype(np.float32, copy=False)
        if body.startswith(b"\x89PNG"):
            millimetres = _png_array(body).astype(np.float32)
            return np.where(millimetres > 0, millimetres / np.float32(_MM_PER_M), np.float32(np.nan))
        raise ValueError("neither npy nor PNG")
    except (ValueError, OSError) as error:
        raise AnswerFormatError(f"the depth answer cannot be read: {error}") from None


def disparity_maps(body: bytes, content_type: str, *, validity: bool, confidence: bool) -> DisparityMaps:
    """The multipart/mixed answer of ``/disparity?validity=true`` (and ``confidence=true``)."""
    parts = multipart_parts(body, content_type)
    wanted = ["disparity"] + ["validity"] * validity + ["confidence"] * confidence
    if missing := [name for name in wanted if name not in parts]:
        raise AnswerFormatError(f"the answer has no part named {', '.join(missing)} "
                                f"(parts: {', '.join(parts)})")
    return DisparityMaps(
        disparity=disparity_map(parts["disparity"][1]),
        validity=_png_array(parts["validity"][1]).astype(np.uint8) if validity else None,
        confidence=_confidence(*parts["confidence"]) if confidence else None,
    )


def multipart_parts(body: bytes, content_type: str) -> dict[str, tuple[str, bytes]]:
    """``name -> (media type, bytes)`` of a multipart body whose parts name themselves in
    ``Content-Disposition`` (RFC 2046: each delimiter is CRLF ``--boundary``)."""
    boundary = _parameter(content_type, "boundary")
    if not content_type.lower().startswith("multipart/") or not boundary:
        raise AnswerFormatError(f"expected a multipart answer, got {content_type!r}")
    parts: dict[str, tuple[str, bytes]] = {}
    for piece in (b"\r\n" + body).split(b"\r\n--" + boundary.encode("latin-1"))[1:]:
        if piece.startswith(b"--"):  # the close delimiter
            return parts
        head, separator, content = piece.partition(b"\r\n\r\n")
        headers = dict(_header(line) for line in head.split(b"\r\n")[1:] if b":" in line)
        name = _parameter(headers.get("content-disposition", ""), "name")
        length = headers.get("content-length")
        if not separator or not name or (length is not None and length != str(len(content))):
            raise AnswerFormatError(f"malformed or truncated multipart part {name or '(unnamed)'!r}")
        parts[name] = (headers.get("content-type", ""), content)
    raise AnswerFormatError("the multipart answer ends without its close delimiter (truncated)")


def point_cloud(body: bytes) -> PointCloud:
    """A binary little-endian PLY (any vertex properties; x, y, z required) as points and colours."""
    end = body.find(b"end_header\n")
    try:
        if not body.startswith(b"ply\n") or end < 0:
            raise ValueError("not a PLY file")
        lines = body[:end].decode("ascii").splitlines()
        if "format binary_little_endian 1.0" not in lines:
            raise ValueError("not binary little-endian")
        element = next(index for index, line in enumerate(lines) if line.startswith("element vertex "))
        count = int(lines[element].split()[2])
        properties = []
        for line in lines[element + 1:]:
            if not line.startswith("property "):
                break
            _, kind, name = line.split()
            properties.append((name, _PLY_TYPES[kind]))
        vertices = np.frombuffer(body, np.dtype(properties), count=count, offset=end + len(b"end_header\n"))
    except (ValueError, KeyError, IndexError, StopIteration, UnicodeDecodeError) as error:
        raise AnswerFormatError(f"the point cloud answer is not a readable binary PLY: {error}") from None
    names = set(vertices.dtype.names or ())
    if not {"x", "y", "z"} <= names:
        raise AnswerFormatError(f"the PLY vertices have no x, y, z (properties: {', '.join(sorted(names))})")
    points = np.stack([vertices[axis] for axis in "xyz"], axis=1).astype(np.float32)
    colors = (np.stack([vertices[c] for c in ("red", "green", "blue")], axis=1).astype(np.uint8)
              if {"red", "green", "blue"} <= names else None)
    return PointCloud(points, colors)


def _confidence(media: str, body: bytes) -> np.ndarray:
    if body.startswith(b"\x93NUMPY"):
        return np.load(io.BytesIO(body), allow_pickle=False).astype(np.float32, copy=False)
    if body.startswith(b"\x89PNG"):  # 8-bit, confidence x 255 (as adsm predict --confidence C.png)
        return _png_array(body).astype(np.float32) / np.float32(255)
    raise AnswerFormatError(f"the confidence part is neither npy nor PNG ({media or 'no media type'})")


def _png_array(body: bytes) -> np.ndarray:
    try:
        with Image.open(io.BytesIO(body)) as image:
            return np.asarray(image)
    except OSError as error:
        raise AnswerFormatError(f"an image part cannot be read: {error}") from None


def _header(line: bytes) -> tuple[str, str]:
    name, _, value = line.decode("latin-1").partition(":")
    return name.strip().lower(), value.strip()


def _parameter(header: str, key: str) -> str | None:
    """A parameter of a header value such as ``attachment; name="validity"`` (quoted or not)."""
    match = re.search(rf'(?:^|;)\s*{key}\s*=\s*(?:"([^"]*)"|([^;\s]*))', header, flags=re.IGNORECASE)
    return None if match is None else match.group(1) if match.group(1) is not None else match.group(2)
