"""Where a disparity map's errors come from: the regions of the issue-11 analysis, as ``adsm eval`` prints.

Every ground-truth pixel falls in exactly one region:

- ``border``: x < true disparity, so its match lies left of the right image (no matching cost can find
  it; only filling or a border strategy can);
- ``rejected``: outside the border strip, invalidated by the inner left-right check (then filled, or
  left missing);
- ``accepted``: the rest, the pixels the matching cost decided.

Accepted pixels are further split by their distance (chessboard, px) to the nearest ground-truth
disparity jump (> ``JUMP`` px between 4-neighbours), with the share of their bad-2 pixels that are
*fattening*: a disparity too large, i.e. the nearer surface bled over the farther one. NumPy only.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from service.validation.codes import VALID

from .metrics import ErrorCounts, count_errors

JUMP = 2.0                                   # px between neighbours that counts as a depth discontinuity
DISTANCE_BINS = ((0, 1), (2, 3), (4, 6), (7, 10), (11, None))   # px from the nearest jump, inclusive
REGIONS = ("border", "rejected", "accepted")


def jump_distance(truth: np.ndarray, *, limit: int = 11) -> np.ndarray:
    """Chessboard distance (px, capped at ``limit``) of each pixel to the nearest disparity jump.

    A jump lies between two known 4-neighbours whose truths differ by more than :data:`JUMP`; both
    pixels of the pair are at distance 0.
    """
    known = np.isfinite(truth)
    filled = np.where(known, truth, 0.0)
    edge = np.zeros(truth.shape, bool)
    horizontal = known[:, 1:] & known[:, :-1] & (np.abs(filled[:, 1:] - filled[:, :-1]) > JUMP)
    vertical = known[1:] & known[:-1] & (np.abs(filled[1:] - filled[:-1]) > JUMP)
    edge[:, 1:] |= horizontal
    edge[:, :-1] |= horizontal
    edge[1:] |= vertical
    edge[:-1] |= vertical
    distance = np.full(truth.shape, limit, np.int32)
    reached = edge
    for step in range(limit):
        distance[reached & (distance == limit)] = step
        grown = reached.copy()   # 3x3 dilation: one chessboard step
        grown[1:] |= reached[:-1]
        grown[:-1] |= reached[1:]
        grown[:, 1:] |= grown[:, :-1].copy()
        grown[:, :-1] |= grown[:, 1:].copy()
        reached = grown
    return distance


def region_masks(truth: np.ndarray, validity: np.ndarray) -> dict[str, np.ndarray]:
    """The three disjoint regions of the ground-truth pixels (see the module docstring)."""
    known = np.isfinite(truth)
    columns = np.arange(truth.shape[1])[None, :]
    border = known & (columns < np.where(known, truth, 0.0))
    rejected = known & ~border & (validity != VALID)
    return {"border": border, "rejected": rejected, "accepted": known & ~border & ~rejected}


class Breakdown:
    """Error counts per region and per distance bin, summed over pairs like :class:`ErrorCounts`."""

    def __init__(self) -> None:
        self.regions = {name: ErrorCounts() for name in REGIONS}
        self.bins = [ErrorCounts() for _ in DISTANCE_BINS]
        self.fattening = [0] * len(DISTANCE_BINS)      # bad-2 pixels whose disparity is too large

    def add(self, disparity: np.ndarray, truth: np.ndarray, validity: np.ndarray) -> Breakdown:
        masks = region_masks(truth, validity)
        for name, mask in masks.items():
            self.regions[name] += count_errors(disparity, truth, mask)
        distance = jump_distance(truth)
        too_large = np.nan_to_num(disparity - truth, nan=0.0) > 2.0
        for index, (low, high) in enumerate(DISTANCE_BINS):
            upper = high if high is not None else np.iinfo(np.int32).max
            in_bin = masks["accepted"] & (distance >= low) & (distance <= upper)
            self.bins[index] += count_errors(disparity, truth, in_bin)
            self.fattening[index] += int((in_bin & too_large).sum())
        return self

    def __iadd__(self, other: Breakdown) -> Breakdown:
        for name in REGIONS:
            self.regions[name] += other.regions[name]
        for index in range(len(DISTANCE_BINS)):
            self.bins[index] += other.bins[index]
            self.fattening[index] += other.fattening[index]
        return self

    def summary(self) -> dict[str, Any]:
        """JSON-ready: per region and per bin the share of ground-truth pixels (%), bad-1/2/3, EPE."""
        total = sum(counts.pixels for counts in self.regions.values())

        def row(counts: ErrorCounts) -> dict[str, Any]:
            figures = counts.summary()
            share = round(100.0 * counts.pixels / total, 4) if total else None
            return {"share": share, **{key: figures[key] for key in ("bad1", "bad2", "bad3", "epe")},
                    "pixels": counts.pixels}

        bins = []
        for (low, high), counts, fattening in zip(DISTANCE_BINS, self.bins, self.fattening, strict=True):
            bad = counts.bad[2]
            bins.append({"distance": f"{low}-{high}" if high is not None else f">={low}", **row(counts),
                         "fattening": round(100.0 * fattening / bad, 2) if bad else None})
        return {"regions": {name: row(self.regions[name]) for name in REGIONS},
                "accepted_by_jump_distance": bins}


def format_breakdown(summary: dict[str, Any]) -> str:
    """The breakdown as text lines under ``adsm eval``'s table."""
    lines = [f"{'region':<12}{'share %':>9}{'bad-1 %':>9}{'bad-2 %':>9}{'bad-3 %':>9}{'EPE px':>9}"]

    def cells(row: dict[str, Any]) -> str:
        return "".join(f"{'-' if row[k] is None else format(row[k], '.2f'):>9}"
                       for k in ("share", "bad1", "bad2", "bad3", "epe"))

    for name, row in summary["regions"].items():
        lines.append(f"{name:<12}{cells(row)}")
    lines.append("accepted pixels by distance to a disparity jump (fattening: bad-2 pixels too large, %)")
    for row in summary["accepted_by_jump_distance"]:
        fattening = "-" if row["fattening"] is None else f"{row['fattening']:.1f}"
        lines.append(f"{row['distance'] + ' px':<12}{cells(row)}{fattening:>9}")
    return "\n".join(lines)
