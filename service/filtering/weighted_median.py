"""Image-guided weighted median of the disparity map, at depth edges only.

Each pixel whose 5x5 neighbourhood spans at least :data:`EDGE_SPREAD` px of disparity (a depth edge,
or an outlier) takes the weighted median of the disparities in its ``(2 RADIUS + 1)^2`` window, with

    w(q) = exp(-|I(p) - I(q)|_1 / (3 SIGMA_COLOUR)) * exp(-|p - q| / SIGMA_SPACE)

(``|.|_1`` over the three channels of the left image, 0-255). Pixels of the same colour vote with
nearly full weight and pixels across an image edge with little, so a foreground disparity that bled
over the background ("fattening": the towers' receptive field sees both sides of the edge) is voted
back to the background's value, and the depth edge moves to the image edge. The median of a window
never invents a value; away from depth edges nothing changes, so sub-pixel precision on smooth surfaces
is kept and the step costs a fraction of SGM. NaN (invalid, unfilled) pixels stay NaN and do not vote.

The constants were chosen on the synthetic validation split (docs/training.md, "Post-processing"): the
lowest bad-2 whose bad-1 is not worse than without the step. The same step ends CNES pandora's and
MC-CNN's pipelines as an unweighted median; the image weights are those of cost-volume filtering stereo
(Hosni et al., 2013; Ma et al., "Constant time weighted median filtering for stereo matching", 2013).
"""

from __future__ import annotations

import numpy as np
from numba import prange

from service.jit import njit

RADIUS = 5  # 11x11 window
SIGMA_COLOUR = 20.0  # grey levels (mean absolute difference over the channels)
SIGMA_SPACE = 5.0  # pixels
EDGE_SPREAD = 1.5  # px of disparity within the 5x5 neighbourhood that mark a depth edge
_EDGE_REACH = 2  # the 5x5 neighbourhood
# The runtime's fastmath minus its no-NaN assumption: NaN marks the invalid pixels here (fill=False).
_NAN_SAFE_FASTMATH = {"nsz", "arcp", "contract", "afn", "reassoc"}


@njit(parallel=True, fastmath=_NAN_SAFE_FASTMATH)
def _filter_rows(  # type: ignore[no-untyped-def]
    disparity, image, radius, colour_weight, space_weight, spread, out
):
    height, width = disparity.shape
    window = (2 * radius + 1) ** 2
    for y in prange(height):
        values = np.empty(window, np.float32)
        weights = np.empty(window, np.float32)
        for x in range(width):
            centre = disparity[y, x]
            out[y, x] = centre
            if np.isnan(centre):
                continue
            low, high = centre, centre
            for yy in range(max(0, y - _EDGE_REACH), min(height, y + _EDGE_REACH + 1)):
                for xx in range(max(0, x - _EDGE_REACH), min(width, x + _EDGE_REACH + 1)):
                    value = disparity[yy, xx]
                    if value < low:
                        low = value
                    if value > high:
                        high = value  # NaN compares false: skipped
            if high - low < spread:
                continue
            count = 0
            total = np.float32(0.0)
            for yy in range(max(0, y - radius), min(height, y + radius + 1)):
                for xx in range(max(0, x - radius), min(width, x + radius + 1)):
                    value = disparity[yy, xx]
                    if np.isnan(value):
                        continue
                    difference = np.int32(0)
                    for channel in range(3):  # uint8 differences would wrap: widen first
                        difference += abs(np.int32(image[y, x, channel]) - np.int32(image[yy, xx, channel]))
                    weight = colour_weight[difference] * space_weight[yy - y + radius, xx - x + radius]
                    values[count] = value
                    weights[count] = weight
                    total += weight
                    count += 1
            out[y, x] = _weighted_select(values, weights, count, total * np.float32(0.5))


@njit(fastmath=_NAN_SAFE_FASTMATH)
def _weighted_select(values, weights, count, half):  # type: ignore[no-untyped-def]
    """The smallest value whose cumulative weight reaches ``half`` (Hoare partitions; O(count) average)."""
    first, last = 0, count - 1
    below = np.float32(0.0)  # weight of the values known to lie left of [first, last]
    while first < last:
        pivot = values[(first + last) // 2]
        i, j = first, last
        while i <= j:
            while values[i] < pivot:
                i += 1
            while values[j] > pivot:
                j -= 1
            if i <= j:
                values[i], values[j] = values[j], values[i]
                weights[i], weights[j] = weights[j], weights[i]
                i += 1
                j -= 1
        # Now [first, j] <= pivot, [i, last] >= pivot and (j, i) == pivot.
        left = np.float32(0.0)
        for k in range(first, j + 1):
            left += weights[k]
        if below + left >= half:
            last = j
            continue
        middle = np.float32(0.0)
        for k in range(j + 1, i):
            middle += weights[k]
        if below + left + middle >= half:
            return pivot
        below += left + middle
        first = i
    return values[first]


def weighted_median(disparity: np.ndarray, image: np.ndarray, *, radius: int = RADIUS,
                    sigma_colour: float = SIGMA_COLOUR, sigma_space: float = SIGMA_SPACE,
                    edge_spread: float = EDGE_SPREAD) -> np.ndarray:
    """float32 HxW: ``disparity`` (float HxW, NaN = invalid) filtered at depth edges, guided by the left
    ``image`` (uint8 HxWx3 of the same size). A new array; the input is not changed.

    >>> import numpy as np
    >>> image = np.zeros((9, 9, 3), np.uint8); image[:, 5:] = 200          # an image edge at x = 5
    >>> disparity = np.full((9, 9), 4.0, np.float32); disparity[:, 4:] = 9.0  # depth edge at x = 4
    >>> weighted_median(disparity, image, radius=3)[4, 3:6].tolist()       # moved to the image edge
    [4.0, 4.0, 9.0]
    """
    disparity = np.ascontiguousarray(disparity, dtype=np.float32)
    if disparity.ndim != 2 or image.shape != (*disparity.shape, 3) or image.dtype != np.uint8:
        raise ValueError(f"image must be uint8 {(*disparity.shape, 3)} for a {disparity.shape} disparity "
                         f"map, got {image.dtype} {image.shape}")
    if radius < 1:
        raise ValueError(f"radius must be >= 1, got {radius}")
    differences = np.arange(3 * 255 + 1, dtype=np.float32)
    colour_weight = np.exp(-differences / (3.0 * sigma_colour)).astype(np.float32)
    offsets = np.arange(-radius, radius + 1, dtype=np.float32)
    space_weight = np.exp(-np.hypot(offsets[:, None], offsets[None]) / sigma_space).astype(np.float32)
    # Numba types a read-only array (a decoded file) apart from a writable one: one specialisation only,
    # the one warm-up compiles.
    image = np.ascontiguousarray(image) if image.flags.writeable else np.array(image)
    if not disparity.flags.writeable:
        disparity = disparity.copy()
    out = np.empty_like(disparity)
    _filter_rows(disparity, image, radius, colour_weight, space_weight,
                 np.float32(edge_spread), out)
    return out
