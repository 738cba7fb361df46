"""Matching cost volume from the two feature maps."""

from service.cost.right_view import right_view_volume
from service.cost.volume import (
    COST_DTYPE,
    MAX_COST_SCALE,
    check_cost_settings,
    checked_volume,
    checked_winners,
    cost_volume,
)
from service.cost.workspace import VolumeWorkspace

__all__ = ["COST_DTYPE", "MAX_COST_SCALE", "VolumeWorkspace", "check_cost_settings", "checked_volume",
           "checked_winners", "cost_volume", "right_view_volume"]
