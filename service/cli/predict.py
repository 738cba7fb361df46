"""`adsm predict LEFT RIGHT -o OUT`: one rectified pair -> a disparity map file.

The format follows OUT's extension (.png -> png16, .npy, .pfm) unless --format says otherwise;
--timings prints the stage timings (seconds) as one JSON line on stderr, so stdout stays clean for
scripts. Every expected failure (missing file, undecodable image, sizes differ, bad model folder, a pair
whose memory plan is over --max-memory-mib) ends with one line ``adsm: error: ...`` and exit status 1,
never a traceback. The sizes and the memory plan (service/memory.py) come from the image headers, so an
oversized pair is refused before it is decoded.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np
from PIL import Image

from service.features import ModelError
from service.io import FORMATS, format_for_path, image_size, read_image, write_disparity
from service.memory import DEFAULT_MAX_REQUEST_BYTES


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "predict",
        help="compute the disparity map of one rectified stereo pair",
        description="Compute the disparity map of one rectified stereo pair and write it to a file.",
    )
    add = parser.add_argument
    add("left", type=Path, metavar="LEFT", help="left image (PNG, JPEG, PPM/PGM, TIFF)")
    add("right", type=Path, metavar="RIGHT", help="right image, same size as the left")
    add("-o", "--output", type=Path, required=True, metavar="OUT", help="disparity map file to write")
    add("--format", choices=FORMATS, help="png16 (x256, 0 invalid), npy (NaN invalid), pfm (inf invalid), "
        "color (RGB PNG for people); default: from OUT's extension")
    add("--max-disparity", type=int, metavar="D", help="disparity range D (default: the model's)")
    add("--model", type=Path, metavar="DIR", help="model folder (default: $ADSM_MODEL_DIR or the shipped)")
    add("--p1", type=float, help="SGM penalty for a 1 px disparity change (cost units)")
    add("--p2", type=float, help="SGM penalty for a larger disparity jump (cost units)")
    add("--no-lr-check", action="store_true", help="skip the inner left-right check")
    add("--no-fill", action="store_true", help="leave invalid pixels unfilled (NaN)")
    add("--no-subpixel", action="store_true", help="integer disparities (no quadratic fit)")
    add("--no-border", action="store_true",
        help="leave the left border band (match left of the right image) as matched")
    add("--validity", type=Path, metavar="PATH", help="also write the validity map (.png or .npy)")
    add("--threads", type=int, metavar="N", help="ONNX Runtime threads (default: the available CPUs)")
    add("--max-memory-mib", type=int, default=DEFAULT_MAX_REQUEST_BYTES // 2**20, metavar="MIB",
        help="refuse a pair whose memory plan (images, features, tower tiles, cost volumes, results) "
        "needs more (default %(default)s)")
    add("--timings", action="store_true", help="print stage timings (seconds) as one JSON line on stderr")
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    started = time.perf_counter()
    output_format = args.format or format_for_path(args.output)
    if args.validity is not None and args.validity.suffix.lower() not in (".png", ".npy"):
        raise ValueError(f"--validity must name a .png or .npy file, got {str(args.validity)!r}")
    if args.max_memory_mib < 1:
        raise ValueError(f"--max-memory-mib must be >= 1, got {args.max_memory_mib}")
    left_size = _size(args.left, "left")
    right_size = _size(args.right, "right")
    if left_size != right_size:
        raise ValueError(
            f"left and right images differ in size: {left_size[1]}x{left_size[0]} vs "
            f"{right_size[1]}x{right_size[0]} (a rectified pair has equal sizes)"
        )

    # Imported here so that `adsm --help` does not pay for Numba.
    from service.matcher import Matcher, MatchOptions

    try:
        matcher = Matcher.from_folder(
            args.model, threads=args.threads, max_request_bytes=args.max_memory_mib * 2**20
        )
    except ModelError as error:
        print(f"adsm: error: bad model folder: {error}", file=sys.stderr)
        return 1
    options = MatchOptions(
        max_disparity=args.max_disparity,
        p1=args.p1,
        p2=args.p2,
        subpixel=not args.no_subpixel,
        lr_check=not args.no_lr_check,
        fill=not args.no_fill,
        border=not args.no_border,
    )
    matcher.check_memory(*left_size, options)  # MemoryLimitError (a ValueError): one line, exit 1
    loaded = time.perf_counter()
    left = _read(args.left, "left")
    right = _read(args.right, "right")
    decoded = time.perf_counter()
    result = matcher(left, right, options)
    matched = time.perf_counter()

    write_disparity(args.output, result.disparity, output_format)
    if args.validity is not None:
        _write_validity(args.validity, result.validity)
    if args.timings:
        stages = {name: seconds for name, seconds in result.timings.items() if name != "total"}
        timings = {"load_model": loaded - started, "decode": decoded - loaded, **stages}
        timings["match"] = matched - decoded
        timings["encode"] = time.perf_counter() - matched
        timings["total"] = time.perf_counter() - started
        print(json.dumps({name: round(seconds, 6) for name, seconds in timings.items()}), file=sys.stderr)
    return 0


def _size(path: Path, side: str) -> tuple[int, int]:
    if not path.is_file():
        raise ValueError(f"{side} image {str(path)!r} does not exist or is not a file")
    return image_size(path, name=f"{side} image {str(path)!r}")


def _read(path: Path, side: str) -> np.ndarray:
    if not path.is_file():
        raise ValueError(f"{side} image {str(path)!r} does not exist or is not a file")
    return read_image(path, name=f"{side} image {str(path)!r}")


def _write_validity(path: Path, validity: np.ndarray) -> None:
    if path.suffix.lower() == ".npy":
        np.save(path, validity, allow_pickle=False)
    else:
        Image.fromarray(validity).save(path, format="PNG")
