"""The one error every calibration reader raises."""

from __future__ import annotations


class CalibrationError(ValueError):
    """A calibration file is missing, malformed or describes an unusable rig.

    The message is one line naming the file and what is wrong, e.g.
    ``calib.txt: cam0 must be a 3x3 matrix [fx 0 cx; 0 fy cy; 0 0 1], got 5 numbers``.
    It is a ``ValueError``, so ``adsm`` prints it as ``adsm: error: ...`` and exits 1.
    """
