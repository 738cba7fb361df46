"""Cost aggregation before the optimisation (the "aggregation" step of the stereo taxonomy)."""

from service.aggregation.shiftable_windows import SHIFT_RADIUS, shiftable_windows

__all__ = ["SHIFT_RADIUS", "shiftable_windows"]
