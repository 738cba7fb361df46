"""The search range of a stereo request, one rule for the CLI, the Python API and the HTTP service.

A call searches the disparities ``[min_disparity, min_disparity + D)`` where ``D`` is ``max_disparity``
(the range *size*, as OpenCV's numDisparities). On an image ``W`` pixels wide only ``-(W - 1) .. W - 1``
can be seen by both cameras, so ``|min_disparity| < W`` and an explicit range must end at ``W - 1`` at the
latest (``min_disparity + D <= W``); a range beyond it asks for the impossible and is refused
(:class:`DisparityRangeError`, HTTP 400). Only the model's default size is clipped to fit, since the caller
did not choose it.
"""

from __future__ import annotations

import dataclasses
from typing import Any


class DisparityRangeError(ValueError):
    """The search range cannot be searched on this image (or is not a range at all)."""


@dataclasses.dataclass(frozen=True)
class SearchRange:
    """Disparities ``minimum .. minimum + count - 1``."""

    minimum: int
    count: int

    @property
    def maximum(self) -> int:
        return self.minimum + self.count - 1


def _integer(name: str, value: Any) -> int:
    if isinstance(value, bool) or not (isinstance(value, int) or hasattr(value, "__index__")):
        raise DisparityRangeError(f"{name} must be an integer, got {value!r}")
    return int(value)


def search_range(width: int, *, min_disparity: int = 0, max_disparity: int | None = None,
                 default_max: int) -> SearchRange:
    """The range a call on an image ``width`` pixels wide searches; :class:`DisparityRangeError` if none.

    >>> search_range(100, max_disparity=None, default_max=128)
    SearchRange(minimum=0, count=100)
    >>> search_range(100, min_disparity=-20, max_disparity=64, default_max=128)
    SearchRange(minimum=-20, count=64)
    """
    minimum = _integer("min_disparity", min_disparity)
    if not -width < minimum < width:
        raise DisparityRangeError(
            f"min_disparity {minimum} leaves no disparity an image {width} pixels wide can hold: "
            f"it must lie in {-(width - 1)}..{width - 1}"
        )
    if max_disparity is None:
        return SearchRange(minimum, min(int(default_max), width - minimum))
    count = _integer("max_disparity", max_disparity)
    if count < 1:
        raise DisparityRangeError(f"max_disparity must be >= 1, got {count}")
    if minimum + count > width:
        start = "" if minimum == 0 else f" from min_disparity {minimum}"
        raise DisparityRangeError(
            f"max_disparity {count} exceeds the image width {width}: at most {width - minimum} "
            f"disparities{start} ({minimum}..{width - 1}) fit"
        )
    return SearchRange(minimum, count)
