"""Codes of the uint8 validity map that travels with every disparity map (docs/architecture.md)."""

from __future__ import annotations

import enum


class Validity(enum.IntEnum):
    """Why a pixel's disparity is, or is not, a direct measurement."""

    VALID = 0
    OCCLUDED = 1  # failed the check and no disparity would have been consistent: hidden on the right
    MISMATCH = 2  # failed the left-right check although some disparity would have been consistent
    NO_DATA = 3  # invalid and unfillable: no valid pixel on any ray
    FILLED_OCCLUSION = 5  # OCCLUDED | FILLED
    FILLED_MISMATCH = 6  # MISMATCH | FILLED

    FILLED = 4  # the bit set on a cause once ray filling gave the pixel a value (not a code on its own)


# Plain ints for the Numba kernels (frozen as compile-time constants).
VALID = int(Validity.VALID)
OCCLUDED = int(Validity.OCCLUDED)
MISMATCH = int(Validity.MISMATCH)
NO_DATA = int(Validity.NO_DATA)
FILLED = int(Validity.FILLED)
