"""scikit-image's bundled photographs, read as plain files: synthetic textures and int8 calibration use them.

scikit-image itself is never imported (its import pulls in SciPy); only the folder its wheel ships is.
"""

from __future__ import annotations

import importlib.util
from pathlib import Path


def data_folder() -> Path:
    """scikit-image's data folder; ModuleNotFoundError (one line) when scikit-image is not installed."""
    spec = importlib.util.find_spec("skimage")
    if spec is None or not spec.submodule_search_locations:
        raise ModuleNotFoundError("scikit-image is not installed", name="skimage")
    return Path(next(iter(spec.submodule_search_locations))) / "data"
