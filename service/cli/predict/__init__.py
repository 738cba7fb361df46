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
import math
import os
import time
from pathlib import Path

from service.cli.match_flags import add_match_flags, match_options
from service.cli.predict import checks, outputs, sources
from service.cli.predict.runner import Runner
from service.cuda import DEVICE_HELP, DEVICES
from service.features import default_model_dir, load_manifest
from service.io import FORMATS
from service.io.video import StereoVideo
from service.limits import RequestLimits
from service.memory import DEFAULT_MAX_REQUEST_BYTES

# Set to 0 to turn Matcher.prepare off (measurements: python -m bench first_call --compare).
PREPARE_ENV = "ADSM_PREPARE"


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
                       "synthetic[:N], synthetic-clean[:N], synthetic-curved[:N], synthetic-fine[:N], "
                       "synthetic-downsampled[:N], motorcycle (train extra)")
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
    add("--device", choices=DEVICES, help=DEVICE_HELP)
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


def run(args: argparse.Namespace) -> int:
    """The command: its pairs and outputs checked (the first pair by its headers) before the model loads,
    then every pair run; the exit status."""
    started = time.perf_counter()
    pairs, batch = sources.pairs(args)
    targets = outputs.targets(args, batch)
    limits = checks.request_limits(args)
    if args.max_depth is not None and not (math.isfinite(args.max_depth) and args.max_depth > 0):
        raise ValueError(f"--max-depth must be a positive number of metres, got {args.max_depth}")
    if (targets.depth or targets.pointcloud) and args.calib is None:
        raise ValueError("--depth and --pointcloud need --calib FILE (focal length and baseline)")
    manifest = load_manifest(args.model if args.model is not None else default_model_dir())
    options = dataclasses.replace(match_options(args), confidence=targets.confidence is not None)
    first_size, first_options = None, options
    if isinstance(pairs, StereoVideo):  # every frame has the header's size: refuse before the model loads
        first_size = checks.check_size(pairs.size, manifest, limits, options)
    elif isinstance(pairs, sources.Samples):
        pass  # a pair's size is known once it is drawn
    elif not batch:  # refuse before the model loads, from the headers alone
        first_size = checks.check_pair(pairs[0], manifest, limits, options)
        outputs.check_paths(targets, pairs[0].name, [pairs[0].left, checks.right_path(pairs[0])])
    elif pairs and pairs[0].right is not None:
        try:  # only to prepare the first call: a bad pair is reported in its turn
            first_size = checks.pair_size(pairs[0])
            first_options = checks.search_options(options, pairs[0].max_disparity, first_size[1])
            checks.check_size(first_size, manifest, limits, first_options)
        except (OSError, ValueError):
            first_size = None

    calibration = None
    if args.calib is not None:
        from service.calibration import read_calibration

        header_size = first_size
        if header_size is None and isinstance(pairs, list):
            header_size = _first_readable_size(pairs)
        calibration = read_calibration(args.calib, image_size=header_size, units=args.calib_units,
                                       rectified=args.rectified)

    # Imported here so that `adsm --help` does not pay for Numba.
    from service.matcher import Matcher

    # Kernels load and cost-volume pages map in the background while the model loads and the images
    # decode; the first call waits for the rest (Matcher.prepare; docs/performance.md, "First call").
    prepare_for = None
    if first_size is not None and os.environ.get(PREPARE_ENV, "1").strip() != "0":
        prepare_for = (*first_size, first_options)
    matcher = Matcher.from_folder(args.model, threads=args.threads, device=args.device,
                                  max_request_bytes=limits.max_request_bytes, prepare_for=prepare_for)
    loaded = time.perf_counter() - started
    runner = Runner(args, matcher, options, targets, calibration, limits, loaded=loaded)
    if isinstance(pairs, StereoVideo):
        shard = sources.shard(args.shard)
        return runner.many(runner.video_items(pairs, shard), sources.video_total(pairs, shard), started)
    if isinstance(pairs, sources.Samples):
        first, step = sources.shard(args.shard) or (0, 1)
        indices = range(first, len(pairs.dataset), step)
        return runner.many(runner.sample_items(pairs.dataset, indices), len(indices), started)
    if not batch:
        runner.one(pairs[0])
        return 0
    return runner.many(runner.file_items(pairs), len(pairs), started)


def _first_readable_size(pairs: list[sources.Pair]) -> tuple[int, int] | None:
    """(height, width) of the first left image whose header reads, for a calibration that needs the image
    size; None when none does. An unreadable image fails its own pair in its turn, not the whole batch."""
    for pair in pairs:
        try:
            return checks.image_size_of(pair.left, "left")
        except (OSError, ValueError):
            continue
    return None
