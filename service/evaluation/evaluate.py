"""Run a Matcher over a dataset and report the benchmark figures (the body of ``adsm eval``).

Search range per pair: the caller's ``max_disparity``, else the dataset's recommendation (KITTI 192,
Middlebury's ndisp, Cones 64, synthetic 128) fitted to the image width, else the model's default; it
starts at ``options.min_disparity``. Seconds per pair are the
Matcher's wall time (reading files excluded); call ``matcher.warmup()`` first so that JIT compilation
is not counted.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable, Sequence
from typing import Any

from service.datasets import StereoSample
from service.limits import recommended_size
from service.matcher import MatchOptions, StereoResult

from .breakdown import Breakdown
from .metrics import ErrorCounts, count_errors
from .sparsification import Sparsification

REPORT_SCHEMA = "adsm-eval/1"

StereoFunction = Callable[[Any, Any, MatchOptions], StereoResult]


def evaluate(matcher: StereoFunction, dataset: Sequence[StereoSample], *, max_disparity: int | None = None,
             options: MatchOptions | None = None,
             on_pair: Callable[[int, dict[str, Any]], None] | None = None) -> dict[str, Any]:
    """Figures over every ground-truth pixel of ``dataset`` (and its non-occluded subset where known).

    ``on_pair(index, pair_report)`` is called after each pair (progress output). Returns a JSON-ready
    report: ``all`` and ``nonoccluded`` summaries, the error ``breakdown`` (border strip, rejected,
    accepted by distance to a disparity jump: ``breakdown.py``), seconds per pair, stage seconds, per pair;
    with ``options.confidence`` also the ``sparsification`` curve (``sparsification.py``).
    """
    options = MatchOptions() if options is None else options
    everything, visible = ErrorCounts(), ErrorCounts()
    masked_pairs, seconds = 0, []
    breakdown = Breakdown()
    sparsification = Sparsification() if options.confidence else None
    stage_seconds: dict[str, float] = {}
    pairs = []
    for index in range(len(dataset)):
        sample = dataset[index]
        search = max_disparity
        if search is None and sample.max_disparity is not None:
            search = recommended_size(sample.max_disparity, sample.left.shape[1],
                                      min_disparity=options.min_disparity)
        search = search or options.max_disparity
        started = time.perf_counter()
        result = matcher(sample.left, sample.right, dataclasses.replace(options, max_disparity=search))
        seconds.append(time.perf_counter() - started)
        for stage, value in result.timings.items():
            stage_seconds[stage] = stage_seconds.get(stage, 0.0) + value
        pair_all = count_errors(result.disparity, sample.disparity)
        everything += pair_all
        pair_breakdown = Breakdown().add(result.disparity, sample.disparity, result.validity)
        breakdown += pair_breakdown
        if sparsification is not None and result.confidence is not None:
            sparsification.add(result.disparity, sample.disparity, result.confidence)
        report = {"name": sample.name, "height": sample.left.shape[0], "width": sample.left.shape[1],
                  "max_disparity": search, "seconds": round(seconds[-1], 4), "all": pair_all.summary(),
                  "nonoccluded": None, "breakdown": pair_breakdown.summary()}
        if sample.nonoccluded is not None:
            pair_visible = count_errors(result.disparity, sample.disparity, sample.nonoccluded)
            visible += pair_visible
            masked_pairs += 1
            report["nonoccluded"] = pair_visible.summary()
        pairs.append(report)
        if on_pair is not None:
            on_pair(index, report)
    if not pairs:
        raise ValueError("the dataset holds no pairs")
    manifest = getattr(matcher, "manifest", {})
    return {
        "schema": REPORT_SCHEMA,
        "model": manifest.get("name"),
        "dataset": getattr(dataset, "name", None),
        "pairs": len(pairs),
        "options": {key: value for key, value in dataclasses.asdict(options).items()
                    if key != "max_disparity"} | {"max_disparity": max_disparity},
        "all": everything.summary(),
        "nonoccluded": visible.summary() if masked_pairs else None,
        "nonoccluded_pairs": masked_pairs,
        "breakdown": breakdown.summary(),
        "seconds_per_pair": round(sum(seconds) / len(seconds), 4),
        "stage_seconds": {stage: round(total / len(pairs), 4) for stage, total in stage_seconds.items()},
        "per_pair": pairs,
    } | ({} if sparsification is None else {"sparsification": sparsification.summary()})
