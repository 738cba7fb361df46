"""The flags that set :class:`service.matcher.MatchOptions`, shared by ``adsm predict`` and ``adsm eval``.

One table of the runtime steps a flag can switch off, so a new step gets its flag, help and wiring in
both commands at once.
"""

from __future__ import annotations

import argparse
from collections.abc import Callable, Sequence
from typing import Any

# MatchOptions field -> help of its --no-<field> flag.
STEP_SWITCHES = {
    "lr_check": "skip the inner left-right check",
    "fill": "leave invalid pixels unfilled (NaN)",
    "background_fill": "fill rejected pixels by MC-CNN's rules (occlusion: the first valid pixel to the "
                       "left; mismatch: the median of 16 rays) instead of leaning to the background",
    "subpixel": "integer disparities (no quadratic fit)",
    "adaptive_p2": "constant SGM jump penalty (not lowered at image edges)",
    "border": "leave the left border band (match left of the right image) as matched",
    "weighted_median": "no image-guided weighted median at depth edges",
}


def add_match_flags(add: Callable[..., Any], *, steps: Sequence[str] = tuple(STEP_SWITCHES)) -> None:
    """``--min-disparity``, ``--p1``, ``--p2`` and a ``--no-<step>`` flag for each of ``steps`` (keys of
    STEP_SWITCHES)."""
    add("--min-disparity", type=int, default=0, metavar="M",
        help="smallest disparity searched: the range is [M, M + D) with D from --max-disparity "
        "(as OpenCV's minDisparity; default 0, negative allowed)")
    add("--p1", type=float, help="SGM penalty for a 1 px disparity change (cost units)")
    add("--p2", type=float, help="SGM penalty for a larger disparity jump (cost units)")
    for step in steps:
        add(f"--no-{step.replace('_', '-')}", action="store_true", help=STEP_SWITCHES[step])


def match_options(args: argparse.Namespace) -> Any:
    """The MatchOptions of parsed flags; a step without its flag in this command stays on."""
    from service.matcher import MatchOptions  # lazily: `adsm --help` need not load Numba

    switches = {step: not getattr(args, f"no_{step}", False) for step in STEP_SWITCHES}
    return MatchOptions(max_disparity=args.max_disparity, min_disparity=args.min_disparity, p1=args.p1,
                        p2=args.p2, **switches)
