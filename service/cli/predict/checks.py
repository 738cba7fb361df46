"""What ``adsm predict`` refuses before anything is decoded or allocated: the server's rules
(service/limits.py: search range, pixels, cost cells, memory plan) applied to a pair's image headers, with
the limits the server would use, its ADSM_* variables, or this command's flags."""

from __future__ import annotations

import argparse
import dataclasses
from pathlib import Path
from typing import TYPE_CHECKING, Any

from service.cli.predict.sources import Pair
from service.io import image_size
from service.limits import ENVIRONMENT, RequestLimits, check_request, recommended_size

if TYPE_CHECKING:  # imported when a pair runs: `adsm --help` must not pay for Numba
    from service.matcher import MatchOptions

# RequestLimits field -> the flag of this command that sets it (the ADSM_* variable does too).
LIMIT_FLAGS = {"max_pixels": "--max-pixels", "max_disparity": "--disparity-limit",
               "max_cost_cells": "--max-cost-cells", "max_request_bytes": "--max-memory-mib"}


def request_limits(args: argparse.Namespace) -> RequestLimits:
    """The server's limits, replaced by the ADSM_* variables that are set, then by the flags."""
    for flag in LIMIT_FLAGS.values():
        value = getattr(args, flag[2:].replace("-", "_"))
        if value is not None and value < 1:
            raise ValueError(f"{flag} must be >= 1, got {value}")
    mib = args.max_memory_mib
    return RequestLimits.from_env(
        max_pixels=args.max_pixels, max_disparity=args.disparity_limit, max_cost_cells=args.max_cost_cells,
        max_request_bytes=None if mib is None else mib * 2**20,
        how={field: f"{flag} or {ENVIRONMENT[field]}" for field, flag in LIMIT_FLAGS.items()},
    )


def check_pair(pair: Pair, manifest: dict[str, Any], limits: RequestLimits, options: MatchOptions
               ) -> tuple[int, int]:
    """The pair's (height, width) once its headers pass every rule the server applies (service/limits.py):
    sizes, range, pixels, cost cells, memory plan; a LimitError or DisparityRangeError otherwise."""
    return check_size(pair_size(pair), manifest, limits, options)


def check_size(size: tuple[int, int], manifest: dict[str, Any], limits: RequestLimits,
               options: MatchOptions) -> tuple[int, int]:
    """``size`` (height, width) once a pair of that size passes the server's rules (see above)."""
    check_request(*size, manifest, limits, min_disparity=options.min_disparity,
                  max_disparity=options.max_disparity, tower_scale=options.tower_scale, who="adsm predict")
    return size


def search_options(options: MatchOptions, recommended: int | None, width: int) -> MatchOptions:
    """``options`` searching a dataset pair's ``recommended`` range when --max-disparity is not given,
    fitted to the image as adsm eval fits it (service/evaluation/evaluate.py): both match the same range."""
    if options.max_disparity is not None or recommended is None:
        return options
    return dataclasses.replace(options, max_disparity=recommended_size(recommended, width,
                                                                       min_disparity=options.min_disparity))


def pair_size(pair: Pair) -> tuple[int, int]:
    """(height, width) of both images by their headers; a ValueError when they differ."""
    left_size = image_size_of(pair.left, "left")
    right_size = image_size_of(right_path(pair), "right")
    if left_size != right_size:
        raise ValueError(
            f"left and right images differ in size: {left_size[1]}x{left_size[0]} vs "
            f"{right_size[1]}x{right_size[0]} (a rectified pair has equal sizes)"
        )
    return left_size


def right_path(pair: Pair) -> Path:
    if pair.right is None:
        raise ValueError(f"no right image named like {pair.left.name}")
    return pair.right


def image_size_of(path: Path, side: str) -> tuple[int, int]:
    """(height, width) of the ``side`` ("left", "right") image at ``path`` by its header."""
    if not path.is_file():
        raise ValueError(f"{side} image {str(path)!r} does not exist or is not a file")
    return image_size(path, name=f"{side} image {str(path)!r}")
