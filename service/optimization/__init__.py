"""Cost aggregation: semi-global matching along 4 scanline paths."""

from service.optimization.sgm import MAX_PENALTY, aggregate

__all__ = ["MAX_PENALTY", "aggregate"]
