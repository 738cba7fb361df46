"""Filling of the pixels the left-right check rejected, and of the left border band."""

from service.filling.border import fill_border_band
from service.filling.rays import BACKGROUND_RUN, fill_invalid

__all__ = ["BACKGROUND_RUN", "fill_border_band", "fill_invalid"]
