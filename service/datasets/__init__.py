"""Stereo datasets for evaluation and training: readers of public layouts and the SPEC parser.

Everything here needs only NumPy and Pillow, so ``adsm eval`` (service) and the trainer (training) read
data the same way. A dataset is a ``Sequence[StereoSample]`` with a ``name``. ``open_dataset`` takes a
SPEC string:

    synthetic[:N]         the first N pairs of the fixed synthetic validation split (default 20); made by
                          the generator of the train extra, found through an entry point (extensions.py)
    synthetic-clean[:N]   the same scenes without camera effects (no noise, blur, gain or JPEG): a
                          diagnostic of how much of the split's error the cameras cause
    synthetic-curved[:N]  the same scenes and cameras with half the objects curved and shaded, and
    synthetic-fine[:N]    with half the surfaces painted at twice the spatial frequency: what the
                          training levers of those names add, measured on a matcher
    synthetic-downsampled[:N]  the split's seeds rendered and photographed at twice the size, then
                          averaged 2 x 2, as the real pairs are downsampled photographs (other scenes:
                          a larger image draws more objects)
    motorcycle            Middlebury 2014's Motorcycle at quarter size, as scikit-image's wheel ships
                          it: a second real pair, evaluation only (train extra)
    kitti2012:PATH        KITTI 2012 (colored_0, colored_1, disp_occ, disp_noc)
    kitti2015:PATH        KITTI 2015 (image_2, image_3, disp_occ_0, disp_noc_0)
    middlebury:PATH       Middlebury 2014 / MiddEval3 scene folders (im0.png, im1.png, disp0GT.pfm)
    cones:PATH            folders with left.png, right.png, disp_left.png [, nonocc_mask.png]
    PATH                  a folder in one of the layouts above, detected from its files
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

from .extensions import open_extension, usages
from .readers import READERS, detect_kind
from .sample import StereoSample

__all__ = ["StereoSample", "open_dataset"]


def open_dataset(spec: str) -> Sequence[StereoSample]:
    """The dataset a SPEC string names (see the module docstring); raises ValueError for a bad SPEC."""
    spec = spec.strip()
    if not spec:
        raise ValueError("empty dataset SPEC")
    kind, _, argument = spec.partition(":")
    if not argument and Path(spec).is_dir():  # a bare folder, even one named like a kind ("cones")
        return READERS[detect_kind(spec)](spec)
    if kind in READERS:
        if not argument:
            raise ValueError(f"dataset {spec!r}: {kind}:PATH needs the dataset folder")
        return READERS[kind](argument)
    dataset = open_extension(spec, kind, argument)
    if dataset is None:
        raise ValueError(f"dataset {spec!r}: expected {', '.join(usages())}, {':PATH, '.join(READERS)}:PATH "
                         "or an existing dataset folder")
    return dataset
