"""The real stereo pairs with ground truth that are kept for evaluation only, and where they lie.

``../shared/data/middlebury2003-cones`` (beside the checkout, as ../shared/DESIGN.md lays it out) and
Middlebury 2014's Motorcycle as scikit-image's wheel ships it (the SPEC ``motorcycle``:
``motorcycle.py``) are measured and reported, never trained, tuned, selected or calibrated on: the
trainer and the int8 calibration refuse what ``EVALUATION_ONLY`` and ``EVALUATION_ONLY_FILES`` name.
Trainer, validation, export, benchmarks and tests read their places from here.
"""

from __future__ import annotations

from pathlib import Path

CONES_NAME = "middlebury2003-cones"    # the folder's name, and the pair's key in a manifest's metrics
MOTORCYCLE_NAME = "middlebury2014-motorcycle"   # the pair's key in a manifest's metrics
MOTORCYCLE_SPEC = "motorcycle"         # its dataset SPEC (train extra: scikit-image's data folder)
# Its files in scikit-image's data folder: the synthetic textures and int8 calibration never read them.
MOTORCYCLE_FILES = ("motorcycle_left.png", "motorcycle_right.png", "motorcycle_disp.npz")
EVALUATION_ONLY = (CONES_NAME, MOTORCYCLE_NAME)   # data sets nothing may be fitted to
EVALUATION_ONLY_FILES = MOTORCYCLE_FILES          # files of them that lie among other data
CONES_FOLDER = Path(__file__).resolve().parents[3] / "shared" / "data" / CONES_NAME
CONES_SPEC = f"cones:{CONES_FOLDER}"   # the folder as a dataset SPEC (service.datasets.open_dataset)
