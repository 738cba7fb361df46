"""Sparsification curve of a confidence map: the bad-N error of the most confident X % of ground-truth pixels.

A confidence that ranks pixels well gives a curve rising from near 0 at 10 % to the all-pixel error at
100 %, monotone; a random one gives a flat line at the all-pixel error. Counts are kept in
:data:`BINS` confidence bins so that a whole dataset adds up in constant memory (like
:class:`~service.evaluation.metrics.ErrorCounts`); within a bin pixels count in proportion, which is
also the expected value for tied confidences (a filled pixel has confidence 0: a quarter of them).
Missing predictions (NaN) count as errors, as in the metrics.
"""

from __future__ import annotations

import dataclasses

import numpy as np

BINS = 4096
FRACTIONS = tuple(range(10, 101, 10))  # percent of the ground-truth pixels, most confident first


@dataclasses.dataclass
class Sparsification:
    threshold: float = 2.0  # bad-N's N, pixels
    pixels: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(BINS, np.int64))
    bad: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(BINS, np.int64))

    def add(self, disparity: np.ndarray, truth: np.ndarray, confidence: np.ndarray) -> Sparsification:
        """Count the ground-truth pixels (finite ``truth``) of one pair; returns self."""
        if not disparity.shape == truth.shape == confidence.shape:
            raise ValueError(f"disparity {disparity.shape}, truth {truth.shape} and confidence "
                             f"{confidence.shape} must have one shape")
        counted = np.isfinite(truth)
        error = np.abs(disparity[counted].astype(np.float64) - truth[counted])
        wrong = ~(error <= self.threshold)  # NaN predictions count as errors
        bins = np.clip((np.nan_to_num(confidence[counted]) * BINS).astype(np.int64), 0, BINS - 1)
        self.pixels += np.bincount(bins, minlength=BINS)
        self.bad += np.bincount(bins, weights=wrong, minlength=BINS).astype(np.int64)
        return self

    def __iadd__(self, other: Sparsification) -> Sparsification:
        self.pixels += other.pixels
        self.bad += other.bad
        return self

    def curve(self, fractions: tuple[int, ...] = FRACTIONS) -> list[float | None]:
        """bad-N % of the ``f`` % most confident pixels for each ``f`` in ``fractions``."""
        total = int(self.pixels.sum())
        if total == 0:
            return [None] * len(fractions)
        pixels = self.pixels[::-1].astype(np.float64)  # most confident bin first
        bad = self.bad[::-1].astype(np.float64)
        taken_before = np.concatenate(([0.0], np.cumsum(pixels)))
        bad_before = np.concatenate(([0.0], np.cumsum(bad)))
        figures = []
        for fraction in fractions:
            wanted = fraction / 100.0 * total
            index = min(int(np.searchsorted(taken_before, wanted, side="right")) - 1, len(pixels) - 1)
            share = (wanted - taken_before[index]) / pixels[index] if pixels[index] else 0.0
            errors = bad_before[index] + share * bad[index]
            figures.append(round(100.0 * errors / wanted, 4) if wanted else None)
        return figures

    def summary(self) -> dict:
        return {"threshold": self.threshold, "fractions": list(FRACTIONS), "bad": self.curve(),
                "pixels": int(self.pixels.sum())}


def format_sparsification(summary: dict) -> str:
    """One table line: ``bad-2 % of the most confident  10 %: 0.00  20 %: 0.03 ...``."""
    cells = "  ".join(f"{fraction} %: {'-' if value is None else format(value, '.2f')}"
                      for fraction, value in zip(summary["fractions"], summary["bad"], strict=True))
    return f"bad-{summary['threshold']:g} % of the most confident pixels  {cells}"
