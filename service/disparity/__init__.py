"""Disparity selection from an aggregated cost volume."""

from service.disparity.wta import left_right_winners, winner_takes_all

__all__ = ["left_right_winners", "winner_takes_all"]
