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
    "right_sgm": "the check's right winners read off the left view's aggregated costs, not from the "
                 "right view's own SGM pass (one SGM pass fewer)",
    "fill": "leave invalid pixels unfilled (NaN)",
    "background_fill": "fill rejected pixels by MC-CNN's rules (occlusion: the first valid pixel to the "
                       "left; mismatch: the median of 16 rays) instead of leaning to the background",
    "subpixel": "integer disparities (no quadratic fit)",
    "adaptive_p2": "constant SGM jump penalty (not lowered at image edges)",
    "weighted_median": "no image-guided weighted median at depth edges",
}

# MatchOptions field -> help of its --<field> / --no-<field> pair: steps whose default is the model's.
MODEL_STEPS = {
    "shiftable_windows": "before SGM, each cost the lowest of its row neighbours' (x +- 1) at the same "
                         "disparity: windows that can shift off a depth edge (default: the model's "
                         "sgm.shiftable_windows)",
    "border": "give the left border band (match left of the right image) the disparity of the surface it "
              "continues; --no-border leaves it as matched (default: the model's filling.border_band)",
}


# MatchOptions fields whose flag, when left out, keeps the runtime's default (not the model's).
RUNTIME_DEFAULTS = ("lr_check_threshold", "border_surface_run")


def add_match_flags(add: Callable[..., Any], *, steps: Sequence[str] = tuple(STEP_SWITCHES)) -> None:
    """``--min-disparity``, ``--tower-scale``, ``--lr-check-threshold``, ``--border-surface-run``,
    ``--p1``, ``--p2``, a ``--no-<step>`` flag for each of ``steps`` (keys of STEP_SWITCHES) and a
    ``--<step>`` / ``--no-<step>`` pair for each of MODEL_STEPS."""
    add("--min-disparity", type=int, default=0, metavar="M",
        help="smallest disparity searched: the range is [M, M + D) with D from --max-disparity "
        "(as OpenCV's minDisparity; default 0, negative allowed)")
    add("--tower-scale", type=int, default=1, metavar="S",
        help="run the feature towers on the pair upsampled by the integer S: sharper depth edges "
        "on clean, densely textured images (Middlebury-like), worse on noisy or compressed ones; "
        "~S^2 times the towers' time (default 1; docs/service.md, \"Tower scale\")")
    add("--lr-check-threshold", type=float, metavar="PX",
        help="largest |DL - DR| in pixels of a pixel the left-right check keeps (default: the runtime's, "
        "service.validation.LR_CHECK_THRESHOLD: the right view's winner must be the pixel's own rounded "
        "disparity, or the step beside it near the half-way point; MC-CNN's 1 keeps more pixels at depth "
        "edges)")
    add("--border-surface-run", type=int, metavar="N",
        help="the left border band ends at a run of N accepted pixels at one disparity that match inside "
        "the right image (default: the runtime's, service.filling.border.SURFACE_RUN; 0 carries every "
        "band to the border)")
    add("--p1", type=float, help="SGM penalty for a 1 px disparity change (cost units)")
    add("--p2", type=float, help="SGM penalty for a larger disparity jump (cost units)")
    for step in steps:
        add(f"--no-{step.replace('_', '-')}", action="store_true", help=STEP_SWITCHES[step])
    for step, text in MODEL_STEPS.items():
        add(f"--{step.replace('_', '-')}", action=argparse.BooleanOptionalAction, default=None, help=text)


def match_options(args: argparse.Namespace) -> Any:
    """The MatchOptions of parsed flags; a step without its --no- flag in this command stays on, a model
    step without its flags takes the model's setting."""
    from service.matcher import MatchOptions  # lazily: `adsm --help` need not load Numba

    switches: dict[str, Any] = {step: not getattr(args, f"no_{step}", False) for step in STEP_SWITCHES}
    switches.update({step: getattr(args, step, None) for step in MODEL_STEPS})  # None: the model's
    # A flag left out keeps MatchOptions' own default, the runtime's constant.
    switches.update({name: value for name in RUNTIME_DEFAULTS if (value := getattr(args, name)) is not None})
    return MatchOptions(max_disparity=args.max_disparity, min_disparity=args.min_disparity,
                        tower_scale=args.tower_scale, p1=args.p1, p2=args.p2, **switches)
