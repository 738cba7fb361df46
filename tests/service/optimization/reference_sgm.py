"""Slow, obviously correct NumPy reference of the runtime's 4-path SGM (eq. (20) of the ADSM paper).

Loops over pixels in float64, one path at a time; only for tests on small volumes.
"""

from __future__ import annotations

import numpy as np


def _path(cost: np.ndarray, p1: float, p2: float, guide: np.ndarray | None = None, edge: float = 0.0
          ) -> np.ndarray:
    """Eq. (20) along axis 1 of a (lines, length, D) volume, from index 0 upwards; with a (lines, length)
    ``guide`` and ``edge`` > 0 the jump penalty is max(P1, round(P2 / (1 + |dI| / edge)))."""
    lines, length, disparities = cost.shape
    result = np.empty(cost.shape, np.float64)
    for line in range(lines):
        result[line, 0] = cost[line, 0]
        for i in range(1, length):
            previous = result[line, i - 1]
            previous_min = previous.min()
            jump = p2
            if guide is not None and edge > 0:
                step = abs(float(guide[line, i]) - float(guide[line, i - 1]))
                jump = max(p1, float(np.rint(np.float32(p2 / (1.0 + step / edge)))))
            for d in range(disparities):
                candidates = [previous[d], previous_min + jump]
                if d > 0:
                    candidates.append(previous[d - 1] + p1)
                if d < disparities - 1:
                    candidates.append(previous[d + 1] + p1)
                result[line, i, d] = cost[line, i, d] + min(candidates) - previous_min
    return result


def reference_sgm(cost: np.ndarray, p1: float, p2: float, guide: np.ndarray | None = None,
                  edge: float = 0.0) -> np.ndarray:
    """Sum over the 4 paths left->right, right->left, top->bottom, bottom->top of an (H, W, D) volume."""
    cost = np.asarray(cost, np.float64)

    def reversed_(lines: np.ndarray | None) -> np.ndarray | None:
        return None if lines is None else lines[:, ::-1]

    columns, columns_guide = cost.transpose(1, 0, 2), None if guide is None else guide.T
    left_to_right = _path(cost, p1, p2, guide, edge)
    right_to_left = _path(cost[:, ::-1], p1, p2, reversed_(guide), edge)[:, ::-1]
    top_to_bottom = _path(columns, p1, p2, columns_guide, edge).transpose(1, 0, 2)
    bottom_to_top = _path(columns[:, ::-1], p1, p2, reversed_(columns_guide), edge)[:, ::-1]
    bottom_to_top = bottom_to_top.transpose(1, 0, 2)
    return left_to_right + right_to_left + top_to_bottom + bottom_to_top
