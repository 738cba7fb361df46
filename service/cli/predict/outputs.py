"""The files ``adsm predict`` writes for a pair: the disparity map in its format, and when asked the
validity and confidence maps, the depth map and the point cloud. Paths are templates holding ``{name}``
(the pair's name); every flag is checked before the model loads."""

from __future__ import annotations

import argparse
import dataclasses
import os
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from PIL import Image

from service.io import format_for_path, write_disparity
from service.io.confidence import encode_confidence

if TYPE_CHECKING:  # imported when a pair runs: `adsm --help` must not pay for Numba or OpenCV
    from service.calibration import StereoCalibration
    from service.matcher import StereoResult

EXTENSION = {"png16": ".png", "npy": ".npy", "pfm": ".pfm", "color": ".png"}


@dataclasses.dataclass(frozen=True)
class Targets:
    disparity: str
    format: str
    validity: str | None
    confidence: str | None
    depth: str | None
    pointcloud: str | None

    def path(self, template: str, name: str) -> Path:
        return Path(template.replace("{name}", name))

    def templates(self) -> dict[str, str]:
        """Flag -> template of every output asked for, the disparity map first."""
        named = {"-o": self.disparity, "--validity": self.validity, "--confidence": self.confidence,
                 "--depth": self.depth, "--pointcloud": self.pointcloud}
        return {flag: template for flag, template in named.items() if template is not None}


def targets(args: argparse.Namespace, batch: bool) -> Targets:
    """The output templates of -o/--out-dir, --format, --validity, --confidence, --depth and --pointcloud,
    each checked (a batch's must hold ``{name}``)."""
    disparity = args.output
    if args.out_dir is not None:
        if disparity is not None:
            raise ValueError("give -o or --out-dir, not both")
        if args.out_dir.exists() and not args.out_dir.is_dir():
            raise ValueError(f"--out-dir {str(args.out_dir)!r} is a file, not a folder")
        disparity = str(args.out_dir / ("{name}" + EXTENSION[args.format or "png16"]))
    if disparity is None:
        raise ValueError("the disparity output is missing: -o OUT (or --out-dir DIR)")
    output_format = args.format or format_for_path(disparity)
    for flag, target in (("--validity", args.validity), ("--confidence", args.confidence)):
        if target is not None and Path(target).suffix.lower() not in (".png", ".npy"):
            raise ValueError(f"{flag} must name a .png or .npy file, got {target!r}")
    if args.depth is not None:
        from service.geometry import depth_format_for_path

        depth_format_for_path(args.depth)
    if args.pointcloud is not None and Path(args.pointcloud).suffix.lower() != ".ply":
        raise ValueError(f"--pointcloud must name a .ply file, got {args.pointcloud!r}")
    templates = {"-o": disparity, "--validity": args.validity, "--confidence": args.confidence,
                 "--depth": args.depth, "--pointcloud": args.pointcloud}
    for flag, template in templates.items():
        if template is not None and batch and "{name}" not in template:
            raise ValueError(f"{flag} {template!r} must hold {{name}} when several pairs are written")
    return Targets(disparity, output_format, args.validity, args.confidence, args.depth, args.pointcloud)


def check_paths(write: Targets, name: str, inputs: Sequence[Path]) -> None:
    """ValueError when two outputs of the pair ``name`` are one file (the second would silently replace the
    first) or an output is one of the pair's ``inputs`` (the image would be overwritten by a map); checked
    before the pair is decoded, so nothing is written."""
    seen: list[tuple[str, Path]] = []
    for flag, template in write.templates().items():
        path = write.path(template, name)
        for source in inputs:
            if _same_file(path, source):
                raise ValueError(f"{flag} {str(path)!r} is the pair's input image {str(source)!r}: writing "
                                 "it would destroy the input; choose another output path")
        for other_flag, other in seen:
            if _same_file(path, other):
                raise ValueError(f"{other_flag} and {flag} name the same file {str(path)!r}: one would "
                                 "overwrite the other; give each output its own path")
        seen.append((flag, path))


def _same_file(first: Path, second: Path) -> bool:
    """The two paths name one file (after ``..``, symbolic links, or as hard links of an existing file)."""
    if first.resolve() == second.resolve():
        return True
    try:
        return os.path.samefile(first, second)
    except OSError:  # one of them does not exist (yet): not the same file
        return False


def write_maps(write: Targets, name: str, result: StereoResult) -> None:
    """The disparity map, then the validity and confidence maps that were asked for."""
    _write(write.path(write.disparity, name),
           lambda path: write_disparity(path, result.disparity, write.format))
    if write.validity is not None:
        _write(write.path(write.validity, name), lambda path: _write_validity(path, result.validity))
    if write.confidence is not None:
        confidence = result.confidence
        assert confidence is not None  # options.confidence follows --confidence (run)
        kind = "npy" if Path(write.confidence).suffix.lower() == ".npy" else "png"  # as targets allows
        data = encode_confidence(confidence, kind)
        _write(write.path(write.confidence, name), lambda path: path.write_bytes(data))


def write_metric(write: Targets, name: str, calibration: StereoCalibration, result: StereoResult,
                 left: np.ndarray, *, drop_filled: bool, max_depth: float | None) -> None:
    """The depth map and the point cloud that were asked for, from the disparity and the calibration."""
    from service.geometry import (
        depth_format_for_path,
        depth_from_disparity,
        encode_depth,
        measured,
        point_cloud_ply,
    )

    disparity = result.disparity
    if drop_filled:
        disparity = np.where(measured(result.validity), disparity, np.float32(np.nan))
    depth = depth_from_disparity(disparity, focal_px=calibration.focal_px,
                                 baseline_m=calibration.baseline_m, doffs=calibration.doffs,
                                 max_depth=max_depth)
    if write.depth:
        path = write.path(write.depth, name)
        data = encode_depth(depth, depth_format_for_path(path))
        _write(path, lambda target: target.write_bytes(data))
    if write.pointcloud:
        body, _count = point_cloud_ply(depth, left, focal_px=calibration.focal_px, cx=calibration.cx,
                                       cy=calibration.cy, focal_y_px=calibration.focal_y_px)
        _write(write.path(write.pointcloud, name), lambda target: target.write_bytes(body))


def _write(path: Path, writer: Callable[[Path], object]) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    writer(path)


def _write_validity(path: Path, validity: np.ndarray) -> None:
    if path.suffix.lower() == ".npy":
        np.save(path, validity, allow_pickle=False)
    else:
        Image.fromarray(validity).save(path, format="PNG")
