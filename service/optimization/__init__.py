"""Cost aggregation: semi-global matching along 4 scanline paths."""

from service.optimization.sgm import MAX_PENALTY, P2_EDGE, PATHS, aggregate

__all__ = ["MAX_PENALTY", "P2_EDGE", "PATHS", "aggregate"]
