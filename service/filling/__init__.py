"""Filling of the pixels the left-right check rejected, and of the left border band."""

from service.filling.border import SURFACE_RUN, fill_border_band
from service.filling.rays import BACKGROUND_RUN, MC_CNN_FRACTION, MC_CNN_RUN, MISMATCH_FRACTION, fill_invalid

__all__ = ["BACKGROUND_RUN", "MC_CNN_FRACTION", "MC_CNN_RUN", "MISMATCH_FRACTION", "SURFACE_RUN",
           "fill_border_band", "fill_invalid"]
