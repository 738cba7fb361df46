"""The real stereo pair with ground truth that is kept for evaluation only, and where it lies.

``../shared/data/middlebury2003-cones`` (beside the checkout, as ../shared/DESIGN.md lays it out) is
measured and reported, never trained, tuned, selected or calibrated on: the trainer and the int8
calibration refuse what ``EVALUATION_ONLY`` names. Trainer, validation, export, benchmarks and tests read
its place from here.
"""

from __future__ import annotations

from pathlib import Path

CONES_NAME = "middlebury2003-cones"    # the folder's name, and the pair's key in a manifest's metrics
EVALUATION_ONLY = (CONES_NAME,)        # data sets nothing may be fitted to
CONES_FOLDER = Path(__file__).resolve().parents[3] / "shared" / "data" / CONES_NAME
CONES_SPEC = f"cones:{CONES_FOLDER}"   # the folder as a dataset SPEC (service.datasets.open_dataset)
