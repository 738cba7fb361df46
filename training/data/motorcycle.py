"""Middlebury 2014's Motorcycle as scikit-image ships it: the second real pair, for evaluation only.

scikit-image's wheel (the train extra) carries ``motorcycle_left.png``, ``motorcycle_right.png`` and
``motorcycle_disp.npz``: the scene at a quarter of its size (741 x 500), disparities 7-60 px, ``inf`` where
the truth is unknown. It is the SPEC ``motorcycle`` (an ``adsm.datasets`` entry point), measured and
reported beside Cones, and like Cones never trained, tuned, selected or calibrated on
(``evaluation_only.py``). The files are read with Pillow and NumPy; scikit-image is never imported.

The package ships no occlusion mask, so ``nonoccluded`` is derived from the left ground truth alone
(``visible_in_right``): the pixels whose match lies inside the right image and is not covered there by a
nearer surface. ``adsm eval --data motorcycle`` and ``python -m export.measure`` read it
(``open_dataset("motorcycle")[0]`` is the ``StereoSample``).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from PIL import Image

from service.datasets import StereoSample
from service.datasets.readers import PairFiles, PairList
from training.data.evaluation_only import MOTORCYCLE_FILES
from training.data.photos import data_folder

MOTORCYCLE_MAX_DISPARITY = 64                   # the truth reaches 59.9 px; Cones uses the same range
# A left pixel counts as covered in the right view when a nearer surface lands on its match with a
# disparity larger by more than this (px): the usual tolerance of a left-right consistency check.
OCCLUSION_TOLERANCE = 1.0
DATASET_NAME = "motorcycle (Middlebury 2014, scikit-image's quarter-size copy)"


def open_motorcycle(argument: str) -> PairList:
    """The dataset SPEC ``motorcycle``, registered for ``service.datasets``; it takes no argument.

    Raises ModuleNotFoundError now when scikit-image is not installed (so that ``adsm eval`` can name the
    extra to install) and FileNotFoundError when its copy lacks one of the files. The pair loads when
    indexed.
    """
    if argument:
        raise ValueError(f"motorcycle takes no argument, got {argument!r}")
    left, right, truth = motorcycle_files()
    files = PairFiles("motorcycle", left, right, truth, max_disparity=MOTORCYCLE_MAX_DISPARITY)
    return PairList(DATASET_NAME, [files], load=load_motorcycle)


def load_motorcycle(files: PairFiles) -> StereoSample:
    """The pair with its ground truth (NaN where unknown) and the derived non-occluded mask."""
    left, right = (_read_rgb(path) for path in (files.left, files.right))
    with np.load(files.disparity, allow_pickle=False) as archive:
        disparity = np.asarray(archive["arr_0"], dtype=np.float32)
    disparity = np.where(np.isfinite(disparity) & (disparity > 0), disparity, np.nan).astype(np.float32)
    return StereoSample(name=files.name, left=left, right=right, disparity=disparity,
                        nonoccluded=visible_in_right(disparity), max_disparity=files.max_disparity)


def visible_in_right(disparity: np.ndarray, *, tolerance: float = OCCLUSION_TOLERANCE) -> np.ndarray:
    """Left pixels of known disparity whose match ``x - d`` is inside the right image and not covered.

    A z-buffer of the right view: every known left pixel lands on the two right columns around ``x - d``
    and the largest disparity there wins; a pixel is hidden when the winner's disparity exceeds its own by
    more than ``tolerance``. Pixels of unknown truth cast no cover, so where they hide a nearer surface the
    mask errs towards visible.

    A background at 1 px with a foreground at 3 px on columns 4-5: column 0 matches left of the image,
    columns 2-3 are hidden behind the foreground in the right view.

    >>> visible_in_right(np.array([[1, 1, 1, 1, 3, 3, 1, 1]], dtype=np.float32)).astype(int).tolist()
    [[0, 1, 0, 0, 1, 1, 1, 1]]
    """
    height, width = disparity.shape
    known = np.isfinite(disparity)
    rows, columns = np.nonzero(known)
    values = disparity[known].astype(np.float64)
    match = columns - values
    cover = np.full((height, width), -np.inf)
    for column in (np.floor(match), np.floor(match) + 1):
        inside = (column >= 0) & (column < width)
        np.maximum.at(cover, (rows[inside], column[inside].astype(np.int64)), values[inside])
    nearest = np.clip(np.round(match), 0, width - 1).astype(np.int64)
    visible = (match >= 0) & (cover[rows, nearest] <= values + tolerance)
    mask = np.zeros((height, width), dtype=bool)
    mask[rows[visible], columns[visible]] = True
    return mask


def motorcycle_files() -> tuple[Path, Path, Path]:
    """Left view, right view and truth in scikit-image's data folder; ModuleNotFoundError without
    scikit-image, FileNotFoundError (one line) when its copy lacks one of them."""
    folder = data_folder()
    left, right, truth = paths = tuple(folder / name for name in MOTORCYCLE_FILES)
    if missing := [path.name for path in paths if not path.is_file()]:
        raise FileNotFoundError(f"scikit-image's data folder {folder} lacks {', '.join(missing)}: "
                                "reinstall scikit-image")
    return left, right, truth


def _read_rgb(path: Path) -> np.ndarray:
    with Image.open(path) as image:
        return np.asarray(image.convert("RGB"), dtype=np.uint8)
