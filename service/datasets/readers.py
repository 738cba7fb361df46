"""Readers for users' copies of public stereo datasets and for the Cones folder layout.

- kitti2012: colored_0/*_10.png, colored_1/*_10.png; truth disp_occ/ (png16); mask: disp_noc/ has a value
- kitti2015: image_2/*_10.png, image_3/*_10.png; truth disp_occ_0/; mask: disp_noc_0/ has a value
- middlebury: folders with im0.png, im1.png (MiddEval3, 2014); truth disp0GT.pfm or disp0.pfm;
  mask0nocc.png == 255; search range from calib.txt's ndisp
- cones: folders with left.png, right.png, disp_left.png (png16); nonocc_mask.png == 255

KITTI folders are PATH or PATH/training; the other layouts are PATH itself or folders two levels below.

Pairs load lazily (one at a time) and come out as ``StereoSample``; unknown ground truth is NaN.
"""

from __future__ import annotations

import dataclasses
import re
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import overload

import numpy as np
from PIL import Image

from service.io import read_disparity, read_image

from .sample import StereoSample

# KITTI's usual search range (its ground truth rarely exceeds it); the Middlebury 2003 quarter-size pairs
# (Cones, Teddy) span less than 64 pixels.
KITTI_MAX_DISPARITY = 192
CONES_MAX_DISPARITY = 64


@dataclasses.dataclass(frozen=True)
class PairFiles:
    name: str
    left: Path
    right: Path
    disparity: Path
    nonoccluded: Path | None = None
    mask_is_disparity: bool = False      # KITTI: the mask is "disp_noc has a value here"
    max_disparity: int | None = None


class PairList(Sequence[StereoSample]):
    """Pairs of one dataset, read from disk when indexed (by ``load``: ``load_pair`` unless a layout
    needs its own reader)."""

    def __init__(self, name: str, pairs: list[PairFiles], *,
                 load: Callable[[PairFiles], StereoSample] | None = None):
        if not pairs:
            raise ValueError(f"{name}: no stereo pairs with ground truth found")
        self.name, self.pairs, self.load = name, pairs, load or load_pair

    def __len__(self) -> int:
        return len(self.pairs)

    @overload
    def __getitem__(self, index: int) -> StereoSample: ...

    @overload
    def __getitem__(self, index: slice) -> list[StereoSample]: ...

    def __getitem__(self, index: int | slice) -> StereoSample | list[StereoSample]:
        if isinstance(index, slice):
            return [self[i] for i in range(*index.indices(len(self)))]
        return self.load(self.pairs[index])


def load_pair(files: PairFiles) -> StereoSample:
    disparity = read_disparity(files.disparity)
    nonoccluded = None
    if files.nonoccluded is not None:
        if files.mask_is_disparity:
            nonoccluded = np.isfinite(read_disparity(files.nonoccluded))
        else:
            with Image.open(files.nonoccluded) as mask:
                nonoccluded = np.asarray(mask.convert("L")) == 255
    return StereoSample(name=files.name, left=read_image(files.left, name=str(files.left)),
                        right=read_image(files.right, name=str(files.right)), disparity=disparity,
                        nonoccluded=nonoccluded, max_disparity=files.max_disparity)


def kitti2012(path: str | Path) -> PairList:
    return _kitti(Path(path), "kitti2012", ("colored_0", "colored_1", "disp_occ", "disp_noc"))


def kitti2015(path: str | Path) -> PairList:
    return _kitti(Path(path), "kitti2015", ("image_2", "image_3", "disp_occ_0", "disp_noc_0"))


def middlebury(path: str | Path) -> PairList:
    pairs = []
    for folder in _folders_with(Path(path), "im0.png"):
        truth = next((folder / n for n in ("disp0GT.pfm", "disp0.pfm") if (folder / n).is_file()), None)
        if truth is None or not (folder / "im1.png").is_file():
            continue  # a test scene without public ground truth
        mask = folder / "mask0nocc.png"
        pairs.append(PairFiles(folder.name, folder / "im0.png", folder / "im1.png", truth,
                               mask if mask.is_file() else None, max_disparity=_ndisp(folder / "calib.txt")))
    return PairList(f"middlebury {path}", pairs)


def cones(path: str | Path) -> PairList:
    pairs = []
    for folder in _folders_with(Path(path), "disp_left.png"):
        mask = folder / "nonocc_mask.png"
        pairs.append(PairFiles(folder.name, folder / "left.png", folder / "right.png",
                               folder / "disp_left.png", mask if mask.is_file() else None,
                               max_disparity=CONES_MAX_DISPARITY))
    return PairList(f"cones {path}", pairs)


READERS = {"kitti2012": kitti2012, "kitti2015": kitti2015, "middlebury": middlebury, "cones": cones}


def detect_kind(path: str | Path) -> str:
    """Which reader fits the folder ``path`` (by its file layout)."""
    root = _existing_folder(Path(path))
    for folder in (root / "training", root):
        if (folder / "colored_0").is_dir():
            return "kitti2012"
        if (folder / "image_2").is_dir():
            return "kitti2015"
    if _folders_with(root, "disp_left.png"):
        return "cones"
    if _folders_with(root, "im0.png"):
        return "middlebury"
    raise ValueError(f"{path}: not a KITTI 2012/2015, Middlebury or Cones folder layout")


def _kitti(root: Path, kind: str, names: tuple[str, str, str, str]) -> PairList:
    root = _existing_folder(root)
    if (root / "training" / names[0]).is_dir():
        root = root / "training"
    left_dir, right_dir, occ_dir, noc_dir = (root / name for name in names)
    pairs = []
    # Only frame 10 of each scene has ground truth; frame 11 is for scene flow.
    for left in sorted(left_dir.glob("*_10.png")):
        right, truth, mask = right_dir / left.name, occ_dir / left.name, noc_dir / left.name
        if right.is_file() and truth.is_file():
            pairs.append(PairFiles(left.stem, left, right, truth, mask if mask.is_file() else None,
                                   mask_is_disparity=True, max_disparity=KITTI_MAX_DISPARITY))
    return PairList(f"{kind} {root}", pairs)


def _folders_with(root: Path, marker: str) -> list[Path]:
    """``root`` itself when it holds ``marker``, else its sub-folders (two levels deep) that do."""
    root = _existing_folder(root)
    if (root / marker).is_file():
        return [root]
    return sorted({p.parent for pattern in (f"*/{marker}", f"*/*/{marker}") for p in root.glob(pattern)})


def _existing_folder(path: Path) -> Path:
    if not path.is_dir():
        raise FileNotFoundError(f"dataset folder {path} does not exist")
    return path


def _ndisp(calib: Path) -> int | None:
    """Middlebury's calib.txt names the search range as ``ndisp=N``."""
    if not calib.is_file():
        return None
    match = re.search(r"^\s*ndisp\s*=\s*(\d+)", calib.read_text(errors="replace"), re.MULTILINE)
    return int(match.group(1)) if match else None
