"""The left border band: pixels whose match lies left of the right image take the surface they continue.

A left pixel at column x with true disparity d > x has no match in the right image: the right camera
never saw it. The cost volume has no cell for it (x - d < 0), so winner-takes-all picks a wrong, smaller
disparity that the left-right check often cannot reject (a right pixel near the border claims it). On
Cones these pixels are 7 % of the ground truth and two thirds of them were bad-2.

Each row is walked from right to left carrying the disparity ``reference`` of the last pixel that passed
the left-right check; a pixel with ``x < reference`` lies in that surface's border band and gets
``reference`` (``FILLED_OCCLUSION``, as an occlusion filled from the right). Constant along the row,
as MC-CNN's occlusion rule: the band is at most ``D`` pixels wide. With a negative disparity ``d`` (a
search range below 0) the band lies along the right border instead (``x - d >= W``), and the row is also
walked from left to right with the same rule mirrored.
Measured with the 13-1deconv3-4conv 32-channel towers (P1/P2 20/160): Cones bad-2 10.50 -> 9.20 %,
EPE 1.61 -> 0.93 px; synthetic:8 bad-2 19.31 -> 16.70 % (docs/training.md, "Post-processing").

The band ends at a surface the right camera saw. A near object close to the border (disparity 50 from
x = 60, say) would otherwise carry its band (x < 50) over a farther surface left of it (disparity 20),
whose pixels at x = 20..29, left of the occlusion beside the object, match inside the right image. So,
inside the band, a pixel that passed the check, matches
inside the right image (``d <= x``) and starts a run of at least ``surface_run`` accepted pixels towards
the border whose disparities stay within :data:`SURFACE_TOLERANCE` of its own becomes the new reference.
A wrong match inside the true band is rarely that consistent: there the winner is any small disparity a
right pixel near the border claims. On the synthetic validation split the band had overwritten 1.6 % of
the ground truth outside the true band (bad-2 of those pixels: 50 % before, 99 % after); the run of 6
(chosen on the split: 4 / 6 / 8 / 12 / 24 px give 17.29 / 17.26 / 17.28 / 17.31 / 17.47 % bad-2 with
adsm-fast at 30/540, 17.67 % without) leaves Cones unchanged (its near objects at the border are the
border's own surface) and Motorcycle level or lower (docs/training.md, "The border band stops at a
surface").
"""

from __future__ import annotations

import numpy as np
from numba import prange

from service.jit import njit
from service.validation.codes import FILLED, OCCLUDED, VALID

_BAND = OCCLUDED | FILLED      # Validity.FILLED_OCCLUSION as a plain int for the kernel
SURFACE_RUN = 6                # accepted pixels at one disparity that end a band (module docstring)
SURFACE_TOLERANCE = 1.0        # px between the disparities of one surface's run


@njit
def _is_surface(disparity, validity, y, x, step, run, tolerance):  # type: ignore[no-untyped-def]
    """Whether ``run`` accepted pixels from (y, x) in direction ``step`` (-1: towards the left border)
    hold disparities within ``tolerance`` of the one at (y, x)."""
    width = disparity.shape[1]
    start = disparity[y, x]
    for k in range(run):
        xx = x + k * step
        if xx < 0 or xx >= width or validity[y, xx] != VALID or abs(disparity[y, xx] - start) > tolerance:
            return False
    return True


@njit(parallel=True)
def _band_rows(disparity, validity, run, tolerance):  # type: ignore[no-untyped-def]
    height, width = disparity.shape
    for y in prange(height):
        # Right band first (x - d >= W, only for negative d), so the left band wins where both reach.
        # Only a negative reference reaches a column there, and only a positive one below: 0 is "none".
        reference = np.float32(0.0)
        for x in range(width):
            if x >= width + reference:
                if (run > 0 and validity[y, x] == VALID and x - disparity[y, x] < width
                        and _is_surface(disparity, validity, y, x, 1, run, tolerance)):
                    reference = disparity[y, x]   # a surface matched inside the right image: band ends
                    continue
                disparity[y, x] = reference
                validity[y, x] = _BAND
            elif validity[y, x] == VALID:
                reference = disparity[y, x]
        reference = np.float32(0.0)
        for x in range(width - 1, -1, -1):
            if x < reference:
                if (run > 0 and validity[y, x] == VALID and disparity[y, x] <= x
                        and _is_surface(disparity, validity, y, x, -1, run, tolerance)):
                    reference = disparity[y, x]
                    continue
                disparity[y, x] = reference
                validity[y, x] = _BAND
            elif validity[y, x] == VALID:
                reference = disparity[y, x]


def fill_border_band(disparity: np.ndarray, validity: np.ndarray, *,
                     surface_run: int = SURFACE_RUN) -> tuple[np.ndarray, np.ndarray]:
    """New (disparity, validity) with the left border band filled; the inputs are not changed.

    ``disparity``: float32 HxW (NaN allowed outside the band); ``validity``: uint8 Validity codes, where
    only ``VALID`` pixels serve as references. ``surface_run``: accepted pixels at one disparity that end a
    band (module docstring); 0 carries every band to the border.

    >>> import numpy as np
    >>> disparity = np.array([[3, 3, 3, 3, 3, 3, 3, 9, 9, 9]], np.float32)   # far surface, then a near one
    >>> validity = np.zeros(disparity.shape, np.uint8)                       # every pixel accepted
    >>> fill_border_band(disparity, validity)[0][0].tolist()                 # the band stops at x = 6
    [3.0, 3.0, 3.0, 3.0, 3.0, 3.0, 3.0, 9.0, 9.0, 9.0]
    >>> fill_border_band(disparity, validity, surface_run=0)[0][0].tolist()  # carried to the border
    [9.0, 9.0, 9.0, 9.0, 9.0, 9.0, 9.0, 9.0, 9.0, 9.0]
    """
    if disparity.ndim != 2 or disparity.shape != validity.shape:
        raise ValueError(f"disparity {disparity.shape} and validity {validity.shape} must be HxW, same shape")
    disparity = np.array(disparity, dtype=np.float32, order="C")
    validity = np.array(validity, dtype=np.uint8, order="C")
    if isinstance(surface_run, bool) or not isinstance(surface_run, int | np.integer) or surface_run < 0:
        raise ValueError(f"surface_run must be an integer >= 0, got {surface_run!r}")
    _band_rows(disparity, validity, int(surface_run), np.float32(SURFACE_TOLERANCE))
    return disparity, validity
