"""Filtering of the finished disparity map (the "filter" step of the stereo taxonomy, after filling)."""

from service.filtering.weighted_median import weighted_median

__all__ = ["weighted_median"]
