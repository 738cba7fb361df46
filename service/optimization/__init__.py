"""Cost aggregation: semi-global matching along 4 scanline paths."""

from service.optimization.sgm import aggregate

__all__ = ["aggregate"]
