"""Box filters by summed-area tables (NumPy only): local sums, means and standard deviations of an image.

    >>> import numpy as np
    >>> float(box_sum(np.ones((3, 4)), 1)[1, 1])   # a 3x3 window inside the image
    9.0
    >>> float(local_std(np.array([[0.0, 2.0] * 3] * 4), 1)[1, 2])
    0.9428090415820634

Windows are (2 radius + 1)^2 pixels centred on each pixel; outside the image the edge pixels repeat, so
every window holds the same number of values. The sums keep the input's dtype: pass float64 where the
image is large and the window sums must be exact to the last grey level.
"""

from __future__ import annotations

import numpy as np

__all__ = ["box_sum", "local_std"]


def box_sum(values: np.ndarray, radius: int) -> np.ndarray:
    """Sum of each pixel's (2 radius + 1)^2 window of a 2-D array, edges repeated; same shape and dtype."""
    padded = np.pad(values, radius, mode="edge")
    summed = padded.cumsum(axis=0).cumsum(axis=1)
    summed = np.pad(summed, ((1, 0), (1, 0)))
    size = 2 * radius + 1
    height, width = values.shape
    return (summed[size : size + height, size : size + width] - summed[:height, size : size + width]
            - summed[size : size + height, :width] + summed[:height, :width])


def local_std(image: np.ndarray, radius: int) -> np.ndarray:
    """Standard deviation of each pixel's (2 radius + 1)^2 window of a 2-D grey image, edges repeated."""
    count = float((2 * radius + 1) ** 2)
    mean = box_sum(image, radius) / count
    square = box_sum(image * image, radius) / count
    return np.sqrt(np.maximum(square - mean * mean, 0.0))
