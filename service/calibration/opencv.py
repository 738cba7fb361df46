"""OpenCV calibration files (YAML, XML or JSON, as ``cv2.FileStorage`` writes them).

Accepted contents, by what ``cv2.stereoCalibrate`` / ``cv2.stereoRectify`` return (OpenCV's
``stereo_calib.cpp`` sample names the camera matrices ``M1``/``M2``; both spellings are read):

- ``P1``, ``P2`` (3x4 rectified projections), optionally ``Q``: a rectified rig. With ``K1 D1 K2 D2 R1
  R2`` as well, the input images are taken as raw and rectified first (unless ``rectified=True``).
- ``Q`` alone: a rectified rig (``StereoCalibration.from_q``).
- ``K1 D1 K2 D2 R T`` (``stereoCalibrate``'s output): ``cv2.stereoRectify`` is run here (alpha 0: only
  valid pixels, so no black border is matched; ``CALIB_ZERO_DISPARITY``: ``doffs`` = 0) for the image
  size in the file (``imageSize``, ``image_size`` = [w, h] or ``image_width``/``image_height``) or the
  one given.

``T`` (and so ``P2[0][3]`` and ``Q``) is in the unit of the calibration target's square size; say which
with ``units`` (``m``, default, ``cm`` or ``mm``).

OpenCV is imported only here and in :mod:`service.calibration.rectify` (docs/service.md says why it is a
runtime dependency): its own parser reads every variant of its files (YAML 1.0 with ``!!opencv-matrix``,
XML, JSON, gzip), and its ``stereoRectify`` is the definition the files were made for.
"""

from __future__ import annotations

import gzip
import io
import re
import zlib
from pathlib import Path
from typing import Any

import numpy as np

from service.calibration._text import MAX_CALIBRATION_BYTES
from service.calibration.errors import CalibrationError
from service.calibration.model import Rectification, StereoCalibration

UNITS = {"m": 1.0, "cm": 0.01, "mm": 0.001}
# OpenCV's parsers recurse once per nesting level and overflow the stack (a segfault that takes the whole
# process down) at 10^4-10^5 levels; a calibration file nests 3 (root, matrix, data), so 64 is generous.
MAX_NESTING = 64
_XML_TAG = re.compile(rb"</|/>|<[A-Za-z_]")
# One YAML line opens a level per leading space, per sequence item ("- ") and per mapping key ("a: "):
# "a: a: a: ... 1" and "- - - ... 1" recurse as deep as nested brackets do.
_YAML_LINE = re.compile(rb"^([ \t]*)(.*)$", re.MULTILINE)
_YAML_OPENERS = re.compile(rb"-[ \t]|:(?:[ \t]|$)")
SUFFIXES = (".yml", ".yaml", ".xml", ".json", ".gz")
_ALIASES = {
    "K1": ("K1", "M1", "cameraMatrix1", "camera_matrix_1"),
    "K2": ("K2", "M2", "cameraMatrix2", "camera_matrix_2"),
    "D1": ("D1", "distCoeffs1", "dist_coeffs_1"),
    "D2": ("D2", "distCoeffs2", "dist_coeffs_2"),
}


def read_opencv(path: str | Path, *, image_size: tuple[int, int] | None = None, units: str = "m",
                rectified: bool = False) -> StereoCalibration:
    """Read an OpenCV stereo calibration file.

    ``image_size`` (height, width) is used when the file has a raw rig and names no size; ``rectified``
    says the images are rectified already (ignore ``K D R1 R2``).

    >>> import cv2, tempfile, numpy as np, os
    >>> path = os.path.join(tempfile.mkdtemp(), "rig.yml")
    >>> fs = cv2.FileStorage(path, cv2.FILE_STORAGE_WRITE)
    >>> fs.write("P1", np.array([[700., 0, 320, 0], [0, 700, 240, 0], [0, 0, 1, 0]]))
    >>> fs.write("P2", np.array([[700., 0, 320, -70], [0, 700, 240, 0], [0, 0, 1, 0]]))
    >>> fs.release()
    >>> read_opencv(path).baseline_m
    0.1
    """
    path = Path(path)
    if units not in UNITS:
        raise CalibrationError(f"calibration units must be one of {', '.join(UNITS)}, got {units!r}")
    scale = UNITS[units]
    source = f"{path.name} (OpenCV)"
    nodes = _read_nodes(path, source)
    size = _size(nodes, source) or image_size
    k1, d1, k2, d2 = (_get(nodes, name) for name in ("K1", "D1", "K2", "D2"))
    have_intrinsics = all(value is not None for value in (k1, d1, k2, d2))
    p1, p2, q = nodes.get("P1"), nodes.get("P2"), nodes.get("Q")
    r1, r2 = nodes.get("R1"), nodes.get("R2")

    if p1 is None or p2 is None:
        r, t = nodes.get("R"), nodes.get("T")
        if have_intrinsics and r is not None and t is not None and not rectified:
            if size is None:
                raise CalibrationError(f"{source}: K1 D1 K2 D2 R T need the image size to rectify; the file "
                                       "names none (imageSize or image_width/image_height)")
            k1, d1, k2, d2, r, t = (_shaped(value, shape, key, source) for value, shape, key in (
                (k1, (3, 3), "K1"), (d1, None, "D1"), (k2, (3, 3), "K2"), (d2, None, "D2"),
                (r, (3, 3), "R"), (t, (3, 1), "T")))
            r1, r2, p1, p2 = _stereo_rectify(k1, d1, k2, d2, r, t, size, source)
        elif q is not None:
            q = _shaped(q, (4, 4), "Q", source).copy()
            q[3, 2] /= scale
            q[3, 3] /= scale
            return StereoCalibration.from_q(q, source=source, size=size)
        else:
            raise CalibrationError(
                f"{source}: no stereo calibration found; expected P1 and P2, Q, or K1 D1 K2 D2 R T "
                f"(found: {', '.join(sorted(nodes)) or 'nothing'})"
            )
    p1 = _shaped(p1, (3, 4), "P1", source)
    p2 = _shaped(p2, (3, 4), "P2", source)
    if abs(p2[1, 3]) > 1e-9 * max(1.0, abs(p2[0, 3])) and abs(p2[1, 3]) > abs(p2[0, 3]):
        raise CalibrationError(f"{source}: P2 describes a vertical rig (P2[1][3] != 0); only left-right "
                               "pairs are supported")
    focal = float(p1[0, 0])
    if focal <= 0:
        raise CalibrationError(f"{source}: P1[0][0] (focal length) must be positive, got {focal}")
    rectification = None
    if have_intrinsics and r1 is not None and r2 is not None and not rectified:
        if size is None:
            raise CalibrationError(
                f"{source}: rectifying raw images needs the image size; the file names none"
            )
        rectification = Rectification(
            k1=_shaped(k1, (3, 3), "K1", source), d1=_shaped(d1, None, "D1", source),
            k2=_shaped(k2, (3, 3), "K2", source), d2=_shaped(d2, None, "D2", source),
            r1=_shaped(r1, (3, 3), "R1", source), r2=_shaped(r2, (3, 3), "R2", source),
            p1=p1, p2=p2, size=size,
        )
    return StereoCalibration(
        focal_px=focal,
        focal_y_px=float(p1[1, 1]) if p1[1, 1] != focal else None,
        baseline_m=float(-p2[0, 3] / p2[0, 0]) * scale,
        cx=float(p1[0, 2]),
        cy=float(p1[1, 2]),
        doffs=float(p2[0, 2] - p1[0, 2]),
        size=size,
        rectification=rectification,
        source=source,
    )


def _read_nodes(path: Path, source: str) -> dict[str, np.ndarray]:
    import cv2

    if not path.is_file():
        raise CalibrationError(f"calibration file {str(path)!r} does not exist or is not a file")
    if path.stat().st_size > MAX_CALIBRATION_BYTES:
        raise CalibrationError(f"{source}: {path.stat().st_size} bytes is too large for a calibration file")
    depth = _nesting_depth(_content(path, source))
    if depth > MAX_NESTING:
        raise CalibrationError(f"{source}: nested {depth} levels deep; a calibration file needs a few "
                               f"(at most {MAX_NESTING})")
    try:
        storage = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    except (cv2.error, SystemError) as error:  # parse errors surface as either
        text = str(error.__cause__ or error).strip()  # SystemError wraps the cv2.error
        reason = text.splitlines()[-1] if text else "unreadable"
        raise CalibrationError(f"{source}: not a readable OpenCV file ({reason[:160]})") from error
    try:
        if not storage.isOpened():
            raise CalibrationError(f"{source}: not a readable OpenCV file")
        root = storage.root()
        if not root.isMap():  # keys() of a sequence or scalar raises a cv2.error
            raise CalibrationError(f"{source}: the top level must name its nodes (P1: ..., P2: ...), "
                                   "not be a list or a value")
        nodes: dict[str, np.ndarray] = {}
        for key in root.keys():  # noqa: SIM118 (a cv2.FileNode, not a dict)
            node = storage.getNode(key)
            value = None
            if node.isMap():
                value = node.mat()  # an !!opencv-matrix / type_id="opencv-matrix" node; None otherwise
            elif node.isSeq() or node.isReal() or node.isInt():
                value = _sequence(node)
            if value is not None:
                nodes[key] = np.asarray(value, dtype=np.float64)
        return nodes
    finally:
        storage.release()


def _content(path: Path, source: str) -> bytes:
    """The bytes OpenCV will parse: the file's, decompressed for ``.gz`` (at most the size cap, so a
    small archive cannot unpack into an unbounded document)."""
    data = path.read_bytes()
    if path.suffix.lower() != ".gz":
        return data
    try:
        with gzip.GzipFile(fileobj=io.BytesIO(data)) as stream:
            text = stream.read(MAX_CALIBRATION_BYTES + 1)
    except (OSError, EOFError, zlib.error) as error:
        raise CalibrationError(f"{source}: not a readable gzip file ({error})") from None
    if len(text) > MAX_CALIBRATION_BYTES:
        raise CalibrationError(f"{source}: unpacks to more than {MAX_CALIBRATION_BYTES} bytes, too large "
                               "for a calibration file")
    return text


def _nesting_depth(data: bytes) -> int:
    """An upper estimate of the document's nesting: the deepest of its bracket ([ {) depth, XML element
    depth and, unless it is JSON or XML, YAML line depth (indentation plus a line's ``- `` items and
    ``key:`` separators)."""
    codes = np.frombuffer(data, np.uint8)
    steps = (np.isin(codes, (ord("["), ord("{"))).astype(np.int64)
             - np.isin(codes, (ord("]"), ord("}"))).astype(np.int64))
    tags = np.array([-1 if tag in (b"</", b"/>") else 1 for tag in _XML_TAG.findall(data)], np.int64)
    deepest = max(_walk_depth(steps), _walk_depth(tags))
    if not data.lstrip().startswith((b"{", b"[", b"<")):
        for indent, rest in _YAML_LINE.findall(data):
            deepest = max(deepest, len(indent) + len(_YAML_OPENERS.findall(rest)))
    return deepest


def _walk_depth(steps: np.ndarray) -> int:
    """Deepest level of a +1/-1 walk that cannot go below 0 (a stray closer is not a negative depth)."""
    if steps.size == 0:
        return 0
    level = np.cumsum(steps)
    floor = np.minimum.accumulate(np.minimum(level, 0))
    return int((level - floor).max())


def _sequence(node: Any) -> np.ndarray | None:  # a cv2.FileNode
    if node.isReal() or node.isInt():
        return np.array([node.real()])
    values = [node.at(i).real() for i in range(node.size()) if node.at(i).isReal() or node.at(i).isInt()]
    return np.array(values) if len(values) == node.size() else None


def _get(nodes: dict[str, np.ndarray], name: str) -> np.ndarray | None:
    for alias in _ALIASES[name]:
        if alias in nodes:
            return nodes[alias]
    return None


def _size(nodes: dict[str, np.ndarray], source: str) -> tuple[int, int] | None:
    for key in ("imageSize", "image_size", "ImageSize"):
        if key in nodes:
            value = nodes[key].ravel()
            if value.size != 2 or (value <= 0).any():
                raise CalibrationError(f"{source}: {key} must be [width, height], got {value.tolist()}")
            return int(value[1]), int(value[0])
    for width_key, height_key in (("image_width", "image_height"), ("width", "height")):
        if width_key in nodes and height_key in nodes:
            return int(nodes[height_key].ravel()[0]), int(nodes[width_key].ravel()[0])
    return None


def _shaped(value: np.ndarray | None, shape: tuple[int, int] | None, key: str, source: str) -> np.ndarray:
    if value is None:
        raise CalibrationError(f"{source}: {key} is missing")
    value = np.asarray(value, dtype=np.float64)
    if not np.isfinite(value).all():
        raise CalibrationError(f"{source}: {key} holds a non-finite value")
    if shape is None:  # distortion: 4, 5, 8, 12 or 14 coefficients, any orientation
        if value.size not in (4, 5, 8, 12, 14):
            raise CalibrationError(f"{source}: {key} must hold 4, 5, 8, 12 or 14 distortion coefficients, "
                                   f"got {value.size}")
        return value.reshape(1, -1)
    if value.size != shape[0] * shape[1]:
        raise CalibrationError(f"{source}: {key} must be {shape[0]}x{shape[1]}, got {value.shape}")
    return value.reshape(shape)


def _stereo_rectify(k1: np.ndarray, d1: np.ndarray, k2: np.ndarray, d2: np.ndarray, r: np.ndarray,
                    t: np.ndarray, size: tuple[int, int], source: str
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    import cv2

    height, width = size
    try:
        r1, r2, p1, p2, _q, _roi1, _roi2 = cv2.stereoRectify(
            k1, d1, k2, d2, (width, height), r, t, flags=cv2.CALIB_ZERO_DISPARITY, alpha=0
        )
    except cv2.error as error:
        raise CalibrationError(f"{source}: cv2.stereoRectify failed on this rig") from error
    return r1, r2, p1, p2
