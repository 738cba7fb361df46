"""Matching cost volume from the two feature maps."""

from service.cost.volume import cost_volume

__all__ = ["cost_volume"]
