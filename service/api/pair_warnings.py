"""Pair diagnostics of a stereo request: is it swapped, unrectified, mostly filled in? (issue 12, item 7)

``adsm predict`` prints them as ``adsm: warning:`` lines; the service sends each as an ``X-ADSM-Warning``
answer header, ``<kind>: <sentence>`` with kind ``swapped``, ``unrectified`` or ``few-valid`` (one header
per warning), and still answers 200. The look (service/calibration/pair_check.py, 0.04-0.1 s for a
Cones-size pair) runs in the inference slot right after the matcher, on the images as matched, and is
reported as the ``check`` stage of Server-Timing; ``diagnostics=false`` skips it.
"""

from __future__ import annotations

import dataclasses
import time

import numpy as np

from service.calibration.pair_check import check_pair
from service.matcher import MatchOptions, StereoResult
from service.protocols import StereoMatcher
from service.validation.codes import Validity

WARNING_HEADER = "X-ADSM-Warning"


@dataclasses.dataclass(frozen=True)
class PairDiagnostics:
    warnings: tuple[str, ...]  # "kind: sentence", the header values
    seconds: float


def match_and_check(matcher: StereoMatcher, left: np.ndarray, right: np.ndarray, options: MatchOptions,
                    diagnostics: bool) -> tuple[float, StereoResult, PairDiagnostics | None]:
    """(when the slot was won, the matcher's result, the diagnostics or None when not asked)."""
    began = time.perf_counter()  # the queue wait ends here
    result = matcher(left, right, options)
    if not diagnostics:
        return began, result, None
    started = time.perf_counter()
    # The check's horizontal search: as adsm predict's, the range asked for, else a quarter of the width.
    reach = None if options.max_disparity is None else options.max_disparity + max(options.min_disparity, 0)
    check = check_pair(left, right, max_disparity=reach)
    valid_share = float(np.mean(result.validity == Validity.VALID)) if options.lr_check else None
    findings = check.findings(valid_share=valid_share, calibration="send the rig's calibration in the calib "
                              "file field", disparity_range="max_disparity / min_disparity")
    return began, result, PairDiagnostics(tuple(f"{kind}: {sentence}" for kind, sentence in findings),
                                          time.perf_counter() - started)
