"""Cost aggregation: semi-global matching along 4 scanline paths."""

from service.optimization.sgm import MAX_PENALTY, P2_EDGE, aggregate

__all__ = ["MAX_PENALTY", "P2_EDGE", "aggregate"]
