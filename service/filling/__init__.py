"""Filling of the pixels the left-right check rejected."""

from service.filling.rays import fill_invalid

__all__ = ["fill_invalid"]
