"""Accuracy of a model on a dataset: benchmark metrics (``metrics``, NumPy only, importable by training
without the runtime) and the loop that runs the Matcher over a dataset (``service.evaluation.evaluate``).
"""

from .metrics import BAD_THRESHOLDS, ErrorCounts, count_errors

__all__ = ["BAD_THRESHOLDS", "ErrorCounts", "count_errors"]
