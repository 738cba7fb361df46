"""Disparity error metrics as the stereo benchmarks define them (NumPy only: no torch, no runtime).

Every ground-truth pixel is counted. A pixel whose predicted disparity is missing (NaN: the runtime
left it invalid) counts as an error for every bad-N and D1 (as KITTI counts missing output); it has no
end-point error, so EPE averages the predicted pixels and ``density`` says how many those are.

- bad-N: % of ground-truth pixels with |d - d_gt| > N (the paper's "N-pixel error", Tables 3-7).
- D1: % of ground-truth pixels with |d - d_gt| > 3 px and > 5 % of d_gt (KITTI 2015's D1-all).
- EPE: mean |d - d_gt| in pixels over the predicted ground-truth pixels.
Counts add up over pairs, so a dataset's figures weigh every pixel alike (as KITTI's devkit does).
"""

from __future__ import annotations

import dataclasses

import numpy as np

BAD_THRESHOLDS = (1, 2, 3, 4, 5)


@dataclasses.dataclass
class ErrorCounts:
    pixels: int = 0                 # ground-truth pixels counted
    predicted: int = 0              # of them, with a finite prediction
    bad: dict[int, int] = dataclasses.field(default_factory=lambda: dict.fromkeys(BAD_THRESHOLDS, 0))
    d1: int = 0
    abs_error: float = 0.0          # summed over the predicted pixels

    def __iadd__(self, other: ErrorCounts) -> ErrorCounts:
        self.pixels += other.pixels
        self.predicted += other.predicted
        for threshold in BAD_THRESHOLDS:
            self.bad[threshold] += other.bad[threshold]
        self.d1 += other.d1
        self.abs_error += other.abs_error
        return self

    def summary(self) -> dict[str, float | int | None]:
        """Percentages (bad-N, D1, density) and EPE in pixels; None where no pixel was counted."""
        def percent(count: int) -> float | None:
            return round(100.0 * count / self.pixels, 4) if self.pixels else None

        figures: dict[str, float | int | None] = {f"bad{t}": percent(self.bad[t]) for t in BAD_THRESHOLDS}
        figures["d1"] = percent(self.d1)
        figures["epe"] = round(self.abs_error / self.predicted, 4) if self.predicted else None
        figures["density"] = percent(self.predicted)
        figures["pixels"] = self.pixels
        return figures


def count_errors(disparity: np.ndarray, truth: np.ndarray, mask: np.ndarray | None = None) -> ErrorCounts:
    """Error counts of ``disparity`` against ``truth`` (both float HxW, NaN = none) on ``mask`` pixels."""
    disparity, truth = np.asarray(disparity), np.asarray(truth)
    if disparity.shape != truth.shape or disparity.ndim != 2:
        raise ValueError(f"disparity {disparity.shape} and ground truth {truth.shape} must be the same HxW")
    counted = np.isfinite(truth)
    if mask is not None:
        if mask.shape != truth.shape:
            raise ValueError(f"mask {mask.shape} does not match the ground truth {truth.shape}")
        counted &= mask.astype(bool)
    reference = truth[counted].astype(np.float64)
    error = np.abs(disparity[counted].astype(np.float64) - reference)
    predicted = np.isfinite(error)
    missing = ~predicted
    counts = ErrorCounts(pixels=int(reference.size), predicted=int(predicted.sum()),
                         abs_error=float(error[predicted].sum()))
    for threshold in BAD_THRESHOLDS:
        counts.bad[threshold] = int(((error > threshold) | missing).sum())
    counts.d1 = int((((error > 3.0) & (error > 0.05 * np.abs(reference))) | missing).sum())
    return counts
