"""`adsm predict`: rectified (or calibrated raw) stereo pairs -> disparity, depth, point cloud files.

One pair::

    adsm predict LEFT RIGHT -o disp.png [--calib FILE --depth depth.npy --pointcloud cloud.ply]

Many pairs in one process (the model is loaded and the kernels compiled once)::

    adsm predict --data RIG_DIR -o 'out/{name}.png' [--depth 'out/{name}.npy'] [--shard I/N]
    adsm predict --pairs LIST.txt --out-dir out/
    adsm predict --data left.mp4,right.mp4 --out-dir out/       # or --data sbs:side_by_side.mp4
    adsm predict --data kitti2015:/data/kitti --out-dir out/     # any `adsm eval` dataset SPEC

``--data DIR`` pairs the files of the same name in ``DIR/left`` and ``DIR/right`` (also ``image_2`` /
``image_3`` and ``image_02/data`` / ``image_03/data``, KITTI's layouts); ``--pairs FILE`` lists one
``LEFT RIGHT`` pair per line; ``--data LEFT_VIDEO,RIGHT_VIDEO`` takes frame i of each video as pair i
and ``--data sbs:VIDEO`` splits each frame of one side-by-side video in halves (service/io/video.py, the
``video`` extra; frames are decoded one at a time, named ``frame_000123``). ``--data KIND:ARGUMENT`` takes
the pairs of an ``adsm eval`` dataset SPEC (service/datasets: ``kitti2012:PATH``, ``kitti2015:PATH``,
``middlebury:PATH``, ``cones:PATH``, ``synthetic[:N]`` with the train extra), the same pairs eval scores,
named as eval names them; a folder in none of the left/right layouts is read as a dataset folder. Their
ground truth is not read; without --max-disparity each pair is searched over the range its dataset
recommends, fitted to the image as eval fits it. Output paths are templates holding ``{name}`` (the left
file's stem, the frame's or the dataset pair's name);
``--out-dir DIR`` is short for ``-o DIR/{name}.<format>``. A progress line per pair and a summary go to
stderr; a pair that fails is reported and skipped, the others are still written, and the exit status is
1 if any failed.

The format follows OUT's extension (.png -> png16, .npy, .pfm) unless --format says otherwise;
--timings prints the stage timings (seconds) as one JSON line on stderr per pair, so stdout stays clean
for scripts. A pair must pass the server's rules (service/limits.py: search range, pixels, cost cells,
memory plan; the limits are the server's defaults, its ADSM_* variables, or the flags), checked on the
image headers before anything is decoded or allocated. Every expected failure (missing file,
undecodable image, sizes differ, bad model folder, bad calibration, a pair over a limit) ends with one
line ``adsm: error: ...`` and exit status 1, never a traceback. Warnings (a pair that looks swapped or
unrectified, few pixels passing the check) are ``adsm: warning: ...`` lines; they do not change the
exit status. The first pair's kernels and cost volumes are prepared in the background while the model
loads (Matcher.prepare; ``ADSM_PREPARE=0`` turns it off, for measurements).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import os
import re
import sys
import time
from collections import Counter
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from PIL import Image

from service.cli.match_flags import add_match_flags, match_options
from service.datasets import StereoSample, extensions, open_dataset
from service.datasets.readers import READERS, PairList, detect_kind
from service.features import default_model_dir, load_manifest
from service.io import FORMATS, format_for_path, image_size, read_pair, write_disparity
from service.io.confidence import encode_confidence
from service.io.video import StereoVideo
from service.limits import ENVIRONMENT, RequestLimits, check_request, recommended_size
from service.memory import DEFAULT_MAX_REQUEST_BYTES

if TYPE_CHECKING:  # imported when a pair runs: `adsm --help` must not pay for Numba or OpenCV
    from service.calibration import StereoCalibration
    from service.calibration.rectify import Rectifier
    from service.matcher import Matcher, MatchOptions, StereoResult

_EXTENSION = {"png16": ".png", "npy": ".npy", "pfm": ".pfm", "color": ".png"}
_LAYOUTS = (("left", "right"), ("image_2", "image_3"), ("image_02/data", "image_03/data"))
_SIDE_BY_SIDE = "sbs:"  # --data sbs:VIDEO
# A SPEC's "WORD:" prefix: one that names no dataset kind is refused as such, not as a missing folder (two
# letters or more: "C:" starts a Windows path).
_KIND_PREFIX = re.compile(r"[A-Za-z][A-Za-z0-9_-]+:")


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "predict",
        help="disparity (and depth, point cloud) of one stereo pair or a folder of pairs",
        description="Compute disparity maps of stereo pairs; with --calib also depth and point clouds.",
    )
    add = parser.add_argument
    add("left", type=Path, metavar="LEFT", nargs="?", help="left image (PNG, JPEG, PPM/PGM, TIFF)")
    add("right", type=Path, metavar="RIGHT", nargs="?", help="right image, same size as the left")
    add("-o", "--output", metavar="OUT",
        help="disparity map file to write (with --data/--pairs: a template holding {name})")
    batch = parser.add_argument_group("many pairs in one process")
    batch.add_argument("--data", metavar="SPEC",
                       help="folder with left/ and right/ (or image_2/ image_3/) holding files of the "
                       "same names; LEFT_VIDEO,RIGHT_VIDEO (frame i of each is pair i); sbs:VIDEO (left "
                       "view in the left half of each frame; videos need the video extra); or an adsm "
                       "eval dataset: kitti2012:PATH, kitti2015:PATH, middlebury:PATH, cones:PATH, "
                       "synthetic[:N] (train extra)")
    batch.add_argument("--pairs", type=Path, metavar="LIST", help="text file, one 'LEFT RIGHT' pair per line")
    batch.add_argument("--out-dir", type=Path, metavar="DIR", help="short for -o DIR/{name}.<format>")
    batch.add_argument("--skip-existing", action="store_true", help="skip pairs whose disparity file exists")
    batch.add_argument("--shard", metavar="I/N", help="process only pairs I, I+N, I+2N, ... (0 <= I < N)")
    add("--format", choices=FORMATS, help="png16 (x256, 0 invalid), npy (NaN invalid), pfm (inf invalid), "
        "color (RGB PNG for people); default: from OUT's extension")
    add("--max-disparity", type=int, metavar="D", help="disparity range D (default: the model's)")
    add("--model", type=Path, metavar="DIR", help="model folder (default: $ADSM_MODEL_DIR or the shipped)")
    add_match_flags(add)
    add("--validity", metavar="PATH", help="also write the validity map (.png or .npy)")
    add("--confidence", metavar="PATH", help="also write the confidence map in [0, 1]: .npy float32, or .png "
        "8-bit (x 255); pixels the left-right check rejected stay under 0.1, missing ones are 0")
    metric = parser.add_argument_group("calibration and metric outputs")
    metric.add_argument("--calib", type=Path, metavar="FILE",
                        help="Middlebury calib.txt, KITTI calib_cam_to_cam.txt, or OpenCV .yml/.xml")
    metric.add_argument("--calib-units", choices=("m", "cm", "mm"), default="m",
                        help="unit of T in an OpenCV file (default m)")
    metric.add_argument("--rectified", action="store_true",
                        help="the images are rectified already although the OpenCV file has K D R1 R2")
    metric.add_argument("--depth", metavar="FILE", help="depth map: .npy (metres), .png (uint16 mm), .pfm")
    metric.add_argument("--pointcloud", metavar="FILE.ply",
                        help="binary PLY, coloured, metres, left camera frame")
    metric.add_argument("--max-depth", type=float, metavar="M", help="no depth beyond M metres")
    metric.add_argument("--drop-filled", action="store_true",
                        help="depth and points only where the disparity was measured (not filled)")
    add("--no-check", action="store_true", help="skip the swapped/unrectified pair diagnostics")
    add("--threads", type=int, metavar="N", help="ONNX Runtime threads (default: the available CPUs)")
    limits = parser.add_argument_group(
        "limits", "the server's limits and ADSM_* variables (service/limits.py); a pair over one is refused "
        "before anything is decoded or allocated")
    defaults = RequestLimits()
    limits.add_argument("--max-pixels", type=int, metavar="N",
                        help=f"pixels per image (default $ADSM_MAX_PIXELS or {defaults.max_pixels})")
    limits.add_argument("--max-cost-cells", type=int, metavar="N", help="height x width x disparities "
                        f"(default $ADSM_MAX_COST_CELLS or {defaults.max_cost_cells})")
    limits.add_argument("--disparity-limit", type=int, metavar="N", help="largest --max-disparity accepted "
                        f"(default $ADSM_MAX_DISPARITY or {defaults.max_disparity})")
    limits.add_argument("--max-memory-mib", type=int, metavar="MIB",
                        help="peak memory of a pair by its plan (images, features, tower tiles, cost "
                        "volumes, results; default $ADSM_MAX_REQUEST_BYTES or "
                        f"{DEFAULT_MAX_REQUEST_BYTES // 2**20})")
    add("--timings", action="store_true", help="print stage timings (seconds) as one JSON line on stderr")
    parser.set_defaults(func=run)


@dataclasses.dataclass(frozen=True)
class _Pair:
    name: str
    left: Path
    right: Path | None  # None: the right image is missing (reported as a failed pair)
    max_disparity: int | None = None  # the search range a dataset recommends (StereoSample's)


@dataclasses.dataclass(frozen=True, eq=False)
class _Frames:
    """A pair decoded from a video, or drawn from a dataset that is not files on disk (synthetic)."""

    name: str
    left: np.ndarray
    right: np.ndarray
    decode_seconds: float
    max_disparity: int | None = None


@dataclasses.dataclass(frozen=True, eq=False)
class _Samples:
    """A dataset whose pairs are made on access (``synthetic:N``): drawn one at a time as they are reached."""

    dataset: Sequence[StereoSample]


@dataclasses.dataclass(frozen=True)
class _Skipped:
    name: str  # --skip-existing: its disparity file is there


@dataclasses.dataclass(frozen=True)
class _Failed:
    name: str
    reason: str  # a video that cannot be decoded further


_Item = _Pair | _Frames | _Skipped | _Failed


@dataclasses.dataclass(frozen=True)
class _Targets:
    disparity: str
    format: str
    validity: str | None
    confidence: str | None
    depth: str | None
    pointcloud: str | None

    def path(self, template: str, name: str) -> Path:
        return Path(template.replace("{name}", name))


# Set to 0 to turn Matcher.prepare off (measurements: python -m bench first_call --compare).
PREPARE_ENV = "ADSM_PREPARE"

# RequestLimits field -> the flag of this command that sets it (the ADSM_* variable does too).
_LIMIT_FLAGS = {"max_pixels": "--max-pixels", "max_disparity": "--disparity-limit",
                "max_cost_cells": "--max-cost-cells", "max_request_bytes": "--max-memory-mib"}


def _limits(args: argparse.Namespace) -> RequestLimits:
    """The server's limits, replaced by the ADSM_* variables that are set, then by the flags."""
    for flag in _LIMIT_FLAGS.values():
        value = getattr(args, flag[2:].replace("-", "_"))
        if value is not None and value < 1:
            raise ValueError(f"{flag} must be >= 1, got {value}")
    mib = args.max_memory_mib
    return RequestLimits.from_env(
        max_pixels=args.max_pixels, max_disparity=args.disparity_limit, max_cost_cells=args.max_cost_cells,
        max_request_bytes=None if mib is None else mib * 2**20,
        how={field: f"{flag} or {ENVIRONMENT[field]}" for field, flag in _LIMIT_FLAGS.items()},
    )


def run(args: argparse.Namespace) -> int:
    started = time.perf_counter()
    pairs, batch = _pairs(args)
    targets = _targets(args, batch)
    limits = _limits(args)
    if args.max_depth is not None and not (math.isfinite(args.max_depth) and args.max_depth > 0):
        raise ValueError(f"--max-depth must be a positive number of metres, got {args.max_depth}")
    if (targets.depth or targets.pointcloud) and args.calib is None:
        raise ValueError("--depth and --pointcloud need --calib FILE (focal length and baseline)")
    manifest = load_manifest(args.model if args.model is not None else default_model_dir())
    options = dataclasses.replace(match_options(args), confidence=targets.confidence is not None)
    first_size, first_options = None, options
    if isinstance(pairs, StereoVideo):  # every frame has the header's size: refuse before the model loads
        first_size = _check_size(pairs.size, manifest, limits, options)
    elif isinstance(pairs, _Samples):
        pass  # a pair's size is known once it is drawn
    elif not batch:  # refuse before the model loads, from the headers alone
        first_size = _check_request(pairs[0], manifest, limits, options)
    elif pairs and pairs[0].right is not None:
        try:  # only to prepare the first call: a bad pair is reported in its turn
            first_size = _check_sizes(pairs[0])
            first_options = _search_options(options, pairs[0].max_disparity, first_size[1])
            _check_size(first_size, manifest, limits, first_options)
        except (OSError, ValueError):
            first_size = None

    calibration = None
    if args.calib is not None:
        from service.calibration import read_calibration

        header_size = first_size
        if header_size is None and isinstance(pairs, list) and pairs and pairs[0].left.is_file():
            header_size = _size(pairs[0].left, "left")
        calibration = read_calibration(args.calib, image_size=header_size, units=args.calib_units,
                                       rectified=args.rectified)

    # Imported here so that `adsm --help` does not pay for Numba.
    from service.matcher import Matcher

    # Kernels load and cost-volume pages map in the background while the model loads and the images
    # decode; the first call waits for the rest (Matcher.prepare; docs/performance.md, "First call").
    prepare_for = None
    if first_size is not None and os.environ.get(PREPARE_ENV, "1").strip() != "0":
        prepare_for = (*first_size, first_options)
    matcher = Matcher.from_folder(args.model, threads=args.threads,
                                  max_request_bytes=limits.max_request_bytes, prepare_for=prepare_for)
    runner = _Runner(args, matcher, options, targets, calibration, limits,
                     loaded=time.perf_counter() - started)
    if isinstance(pairs, StereoVideo):
        return runner.many(runner.video_items(pairs, _shard(args.shard)), _video_total(pairs, args), started)
    if isinstance(pairs, _Samples):
        first, step = _shard(args.shard) or (0, 1)
        indices = range(first, len(pairs.dataset), step)
        return runner.many(runner.sample_items(pairs.dataset, indices), len(indices), started)
    if not batch:
        runner.one(pairs[0])
        return 0
    return runner.many(runner.file_items(pairs), len(pairs), started)


class _Runner:
    """Runs pairs through one loaded matcher and writes their files."""

    def __init__(self, args: argparse.Namespace, matcher: Matcher, options: MatchOptions, targets: _Targets,
                 calibration: StereoCalibration | None, limits: RequestLimits, *, loaded: float) -> None:
        self.args, self.matcher, self.options, self.targets = args, matcher, options, targets
        self.calibration = calibration
        self.limits = limits
        self.rectifier: Rectifier | None = None
        self.load_seconds = loaded

    def one(self, pair: _Pair | _Frames) -> None:
        begun = time.perf_counter()
        if isinstance(pair, _Frames):
            size = (pair.left.shape[0], pair.left.shape[1])
            begun -= pair.decode_seconds
        else:
            size = _check_sizes(pair)
        options = _search_options(self.options, pair.max_disparity, size[1])
        _check_size(size, self.matcher.manifest, self.limits, options)
        if isinstance(pair, _Frames):
            left, right = pair.left, pair.right
        else:
            left, right = read_pair(pair.left, _right_path(pair), names=(f"left image {str(pair.left)!r}",
                                                                          f"right image {str(pair.right)!r}"))
        calibration = None if self.calibration is None else self.calibration.for_size(*size)
        if calibration is not None and calibration.needs_rectification:
            if self.rectifier is None:
                from service.calibration.rectify import Rectifier

                self.rectifier = Rectifier(calibration)
            left, right = self.rectifier(left, right)
        decoded = time.perf_counter()
        result = self.matcher(left, right, options)
        matched = time.perf_counter()
        name = pair.name
        write = self.targets
        _write(write.path(write.disparity, name),
               lambda path: write_disparity(path, result.disparity, write.format))
        if write.validity is not None:
            _write(write.path(write.validity, name), lambda path: _write_validity(path, result.validity))
        if write.confidence is not None:
            confidence = result.confidence
            assert confidence is not None  # options.confidence follows --confidence (run)
            kind = "npy" if Path(write.confidence).suffix.lower() == ".npy" else "png"  # as _targets allows
            data = encode_confidence(confidence, kind)
            _write(write.path(write.confidence, name), lambda path: path.write_bytes(data))
        if calibration is not None and (write.depth or write.pointcloud):
            self._metric(name, calibration, result, left)
        if not self.args.no_check:
            self._diagnose(pair.name, left, right, result)
        if self.args.timings:
            stages = {stage: seconds for stage, seconds in result.timings.items() if stage != "total"}
            timings = {"load_model": self.load_seconds, "decode": decoded - begun, **stages}
            timings["match"] = matched - decoded
            timings["encode"] = time.perf_counter() - matched
            timings["total"] = time.perf_counter() - begun + self.load_seconds
            self.load_seconds = 0.0  # paid once
            rounded = {stage: round(seconds, 6) for stage, seconds in timings.items()}
            print(json.dumps(rounded), file=sys.stderr)

    def file_items(self, pairs: list[_Pair]) -> Iterator[_Item]:
        for pair in pairs:
            yield _Skipped(pair.name) if self._written(pair.name) else pair

    def video_items(self, video: StereoVideo, shard: tuple[int, int] | None) -> Iterator[_Item]:
        """The shard's frames of ``video`` as pairs, decoded as they are reached; frames of other shards
        and --skip-existing ones are passed over (StereoVideo.pairs: not converted, not decoded where the
        codec allows)."""
        first, step = shard or (0, 1)

        def wanted(index: int) -> bool:
            return index % step == first and not self._written(_frame_name(index))

        frames, index = video.pairs(wanted), -1
        while True:
            begun = time.perf_counter()
            try:
                frame = next(frames)
            except StopIteration:
                return
            except ValueError as error:  # the stream cannot go on: the failure ends the video
                yield _Failed(_frame_name(index + 1), str(error))
                return
            index = frame.index
            if index % step != first:
                continue
            name = _frame_name(index)
            if frame.error is not None:
                yield _Failed(name, frame.error)
            elif frame.views is None:
                yield _Skipped(name)
            else:
                yield _Frames(name, *frame.views, time.perf_counter() - begun)

    def many(self, items: Iterator[_Item], total: int | None, started: float) -> int:
        failed: list[str] = []
        skipped = done = 0
        for index, pair in enumerate(items, start=1):
            if isinstance(pair, _Skipped):
                skipped += 1
                continue
            begun = time.perf_counter()
            try:
                if isinstance(pair, _Failed):
                    raise ValueError(pair.reason)
                if isinstance(pair, _Pair) and pair.right is None:
                    raise ValueError(f"no right image named like {pair.left.name}")
                if isinstance(pair, _Frames):
                    begun -= pair.decode_seconds
                self.one(pair)
            except (OSError, ValueError) as error:
                failed.append(pair.name)
                print(f"adsm: error: {pair.name}: {error}", file=sys.stderr)
                continue
            done += 1
            rate = done / max(time.perf_counter() - started, 1e-9)
            print(f"[{index}/{'?' if total is None else total}] {pair.name} "
                  f"{time.perf_counter() - begun:.2f} s ({rate:.2f} pairs/s)", file=sys.stderr)
        elapsed = time.perf_counter() - started
        summary = f"adsm: {done} pairs written, {skipped} skipped, {len(failed)} failed in {elapsed:.1f} s"
        if done:
            summary += f" ({done / elapsed:.2f} pairs/s)"
        if failed:
            summary += ": " + ", ".join(failed[:10]) + (" ..." if len(failed) > 10 else "")
        print(summary, file=sys.stderr)
        return 1 if failed else 0

    def sample_items(self, dataset: Sequence[StereoSample], indices: range) -> Iterator[_Item]:
        """The pairs ``indices`` of ``dataset``, each drawn when it is reached; a pair's name is known once
        it is drawn, so --skip-existing skips it after that (generating is what there is to save)."""
        seen: set[str] = set()
        for index in indices:
            begun = time.perf_counter()
            try:
                sample = dataset[index]
            except (OSError, ValueError) as error:
                yield _Failed(f"pair {index}", str(error))
                continue
            if sample.name in seen:  # its outputs would overwrite the other pair's
                yield _Failed(sample.name, "another pair of the dataset has this name")
            elif self._written(sample.name):
                yield _Skipped(sample.name)
            else:
                yield _Frames(sample.name, sample.left, sample.right, time.perf_counter() - begun,
                              sample.max_disparity)
            seen.add(sample.name)

    def _written(self, name: str) -> bool:
        """--skip-existing and the pair's disparity file is there."""
        return bool(self.args.skip_existing) and self.targets.path(self.targets.disparity, name).exists()

    def _metric(self, name: str, calibration: StereoCalibration, result: StereoResult,
                left: np.ndarray) -> None:
        from service.geometry import (
            depth_format_for_path,
            depth_from_disparity,
            encode_depth,
            measured,
            point_cloud_ply,
        )

        disparity = result.disparity
        if self.args.drop_filled:
            disparity = np.where(measured(result.validity), disparity, np.float32(np.nan))
        depth = depth_from_disparity(disparity, focal_px=calibration.focal_px,
                                     baseline_m=calibration.baseline_m, doffs=calibration.doffs,
                                     max_depth=self.args.max_depth)
        if self.targets.depth:
            path = self.targets.path(self.targets.depth, name)
            data = encode_depth(depth, depth_format_for_path(path))
            _write(path, lambda target: target.write_bytes(data))
        if self.targets.pointcloud:
            body, _count = point_cloud_ply(depth, left, focal_px=calibration.focal_px, cx=calibration.cx,
                                           cy=calibration.cy, focal_y_px=calibration.focal_y_px)
            _write(self.targets.path(self.targets.pointcloud, name), lambda target: target.write_bytes(body))

    def _diagnose(self, name: str, left: np.ndarray, right: np.ndarray, result: StereoResult) -> None:
        from service.calibration.pair_check import check_pair
        from service.validation.codes import Validity

        valid_share = float((result.validity == Validity.VALID).mean()) if self.options.lr_check else None
        check = check_pair(left, right, max_disparity=self.args.max_disparity or left.shape[1] // 4)
        for warning in check.warnings(valid_share=valid_share):
            print(f"adsm: warning: {name}: {warning}", file=sys.stderr)


def _pairs(args: argparse.Namespace) -> tuple[list[_Pair] | StereoVideo | _Samples, bool]:
    sources = [args.left is not None, args.data is not None, args.pairs is not None]
    if sum(sources) != 1:
        raise ValueError("give LEFT RIGHT, or --data SPEC, or --pairs LIST (exactly one of them)")
    if args.left is not None:
        if args.right is None:
            raise ValueError("RIGHT is missing: give LEFT RIGHT")
        return [_Pair(args.left.stem, args.left, args.right)], False
    shard = _shard(args.shard)  # a bad I/N is refused before a video is opened
    if args.data is not None and _names_a_dataset(args.data):
        found = _dataset(args.data)
        if isinstance(found, _Samples):
            return found, True  # sharded as it is drawn (run)
        pairs = found
    else:
        videos = _videos(args.data) if args.data is not None else None
        if videos is not None:
            return StereoVideo.open(*videos, warn=_warn), True
        pairs = _folder_pairs(Path(args.data)) if args.data is not None else _listed_pairs(args.pairs)
    if shard is not None:
        index, count = shard
        pairs = pairs[index::count]
    return pairs, True


def _videos(spec: str) -> tuple[Path, Path | None] | None:
    """``(left, right)`` video files of a --data SPEC, ``(video, None)`` for ``sbs:VIDEO``, None for a
    folder. ``A,B`` splits at the comma that leaves two existing files (a name may hold a comma)."""
    if spec.startswith(_SIDE_BY_SIDE):
        return Path(spec[len(_SIDE_BY_SIDE):]), None
    if Path(spec).is_dir():
        return None
    if "," in spec:
        splits = [(Path(spec[:at]), Path(spec[at + 1:])) for at, char in enumerate(spec) if char == ","]
        return next((split for split in splits if split[0].is_file() and split[1].is_file()), splits[0])
    if Path(spec).is_file():
        raise ValueError(f"--data {spec!r} is one file: give two videos as LEFT,RIGHT, or "
                         f"{_SIDE_BY_SIDE}VIDEO for a side-by-side video, or a folder")
    return None


def _video_total(video: StereoVideo, args: argparse.Namespace) -> int | None:
    """How many pairs this run's shard holds by the headers (None when a container does not tell)."""
    first, step = _shard(args.shard) or (0, 1)
    return None if video.frame_count is None else len(range(first, video.frame_count, step))


def _frame_name(index: int) -> str:
    return f"frame_{index:06d}"


def _warn(message: str) -> None:
    print(f"adsm: warning: {message}", file=sys.stderr)


def _dataset_kinds() -> list[str]:
    """The kinds an ``adsm eval`` SPEC may start with: the readers' and those of extras (installed or not)."""
    return [*READERS, *sorted(set(extensions.EXTRA_KINDS) | set(extensions.registered()))]


def _names_a_dataset(spec: str) -> bool:
    """True when ``spec`` starts with a dataset kind (``kitti2015:PATH``, ``synthetic``); an existing file
    or folder named like a bare kind ("cones") is that file or folder, as open_dataset reads it."""
    kind, colon, _ = spec.partition(":")
    return kind in _dataset_kinds() and (bool(colon) or not Path(spec).exists())


def _dataset(spec: str) -> list[_Pair] | _Samples:
    """The pairs of an ``adsm eval`` dataset SPEC, in eval's order and with eval's names. Pairs on disk are
    read as the folder form reads them (headers checked first; the ground truth is not read)."""
    dataset = open_dataset(spec)
    if not isinstance(dataset, PairList):
        return _Samples(dataset)
    pairs = [_Pair(files.name, files.left, files.right, files.max_disparity) for files in dataset.pairs]
    twice = sorted(name for name, count in Counter(pair.name for pair in pairs).items() if count > 1)
    if twice:  # Middlebury's trainingQ/ and trainingH/ hold scenes of the same names
        raise ValueError(f"--data {spec!r}: several pairs are named {', '.join(twice[:3])}; outputs would "
                         "collide: point --data at one folder of them")
    return pairs


def _spec_forms() -> str:
    readers = ", ".join(f"{kind}:PATH" for kind in READERS)
    return (f"{readers}, {', '.join(extensions.usages())}, LEFT_VIDEO,RIGHT_VIDEO, {_SIDE_BY_SIDE}VIDEO "
            "or a folder with left/ and right/")


def _folder_pairs(root: Path) -> list[_Pair]:
    if not root.is_dir():
        prefix = _KIND_PREFIX.match(str(root))
        if prefix:
            raise ValueError(f"--data {str(root)!r}: unknown dataset kind {prefix.group()[:-1]!r}; "
                             f"expected {_spec_forms()}")
        raise ValueError(f"--data {str(root)!r} is not a folder (nor LEFT,RIGHT or "
                         f"{_SIDE_BY_SIDE}VIDEO videos)")
    for left_name, right_name in _LAYOUTS:
        left_dir, right_dir = root / left_name, root / right_name
        if left_dir.is_dir() and right_dir.is_dir():
            lefts = {path.name: path for path in left_dir.iterdir()
                     if path.is_file() and not path.name.startswith(".")}
            rights = {path.name: path for path in right_dir.iterdir() if path.is_file()}
            if not lefts:
                raise ValueError(f"--data: {left_dir} holds no files")
            return [_Pair(Path(name).stem, lefts[name], rights.get(name)) for name in sorted(lefts)]
    try:
        kind = detect_kind(root)
    except ValueError:
        layouts = ", ".join(f"{left}/ + {right}/" for left, right in _LAYOUTS)
        raise ValueError(f"--data {str(root)!r}: no pair of folders ({layouts}) and no dataset layout "
                         "(KITTI 2012/2015, Middlebury, Cones)") from None
    found = _dataset(f"{kind}:{root}")
    assert isinstance(found, list)  # the readers' datasets are files on disk
    return found


def _listed_pairs(listing: Path) -> list[_Pair]:
    if not listing.is_file():
        raise ValueError(f"--pairs {str(listing)!r} does not exist or is not a file")
    pairs = []
    for number, line in enumerate(listing.read_text(encoding="utf-8").splitlines(), start=1):
        fields = line.split()
        if not fields or fields[0].startswith("#"):
            continue
        if len(fields) != 2:
            raise ValueError(
                f"--pairs {listing.name} line {number}: expected 'LEFT RIGHT', got {line.strip()!r}"
            )
        left = Path(fields[0]) if Path(fields[0]).is_absolute() else listing.parent / fields[0]
        right = Path(fields[1]) if Path(fields[1]).is_absolute() else listing.parent / fields[1]
        pairs.append(_Pair(left.stem, left, right))
    names = [pair.name for pair in pairs]
    if len(set(names)) != len(names):
        raise ValueError(f"--pairs {listing.name}: two left images share a file stem; outputs would collide")
    return pairs


def _shard(text: str | None) -> tuple[int, int] | None:
    if text is None:
        return None
    try:
        index, count = (int(part) for part in text.split("/"))
    except ValueError:
        raise ValueError(f"--shard must be I/N with integers, got {text!r}") from None
    if not 0 <= index < count:
        raise ValueError(f"--shard I/N needs 0 <= I < N, got {text!r}")
    return index, count


def _targets(args: argparse.Namespace, batch: bool) -> _Targets:
    disparity = args.output
    if args.out_dir is not None:
        if disparity is not None:
            raise ValueError("give -o or --out-dir, not both")
        disparity = str(args.out_dir / ("{name}" + _EXTENSION[args.format or "png16"]))
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
    return _Targets(disparity, output_format, args.validity, args.confidence, args.depth, args.pointcloud)


def _check_request(pair: _Pair, manifest: dict[str, Any], limits: RequestLimits, options: MatchOptions
                   ) -> tuple[int, int]:
    """The pair's (height, width) once its headers pass every rule the server applies (service/limits.py):
    sizes, range, pixels, cost cells, memory plan; a LimitError or DisparityRangeError otherwise."""
    return _check_size(_check_sizes(pair), manifest, limits, options)


def _check_size(size: tuple[int, int], manifest: dict[str, Any], limits: RequestLimits,
                options: MatchOptions) -> tuple[int, int]:
    """``size`` (height, width) once a pair of that size passes the server's rules (see above)."""
    check_request(*size, manifest, limits, min_disparity=options.min_disparity,
                  max_disparity=options.max_disparity, who="adsm predict")
    return size


def _search_options(options: MatchOptions, recommended: int | None, width: int) -> MatchOptions:
    """``options`` searching a dataset pair's ``recommended`` range when --max-disparity is not given,
    fitted to the image as adsm eval fits it (service/evaluation/evaluate.py): both match the same range."""
    if options.max_disparity is not None or recommended is None:
        return options
    return dataclasses.replace(options, max_disparity=recommended_size(recommended, width,
                                                                       min_disparity=options.min_disparity))


def _check_sizes(pair: _Pair) -> tuple[int, int]:
    left_size = _size(pair.left, "left")
    right_size = _size(_right_path(pair), "right")
    if left_size != right_size:
        raise ValueError(
            f"left and right images differ in size: {left_size[1]}x{left_size[0]} vs "
            f"{right_size[1]}x{right_size[0]} (a rectified pair has equal sizes)"
        )
    return left_size


def _right_path(pair: _Pair) -> Path:
    if pair.right is None:
        raise ValueError(f"no right image named like {pair.left.name}")
    return pair.right


def _size(path: Path, side: str) -> tuple[int, int]:
    if not path.is_file():
        raise ValueError(f"{side} image {str(path)!r} does not exist or is not a file")
    return image_size(path, name=f"{side} image {str(path)!r}")


def _write(path: Path, writer: Callable[[Path], object]) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    writer(path)


def _write_validity(path: Path, validity: np.ndarray) -> None:
    if path.suffix.lower() == ".npy":
        np.save(path, validity, allow_pickle=False)
    else:
        Image.fromarray(validity).save(path, format="PNG")
