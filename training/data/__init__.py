"""Training data: patch pairs and dense crops (torch) cut from the datasets in ``service.datasets``.

The readers and the synthetic generator live in ``service.datasets`` (NumPy + Pillow only), because
``adsm eval`` in the runtime reads the same data and the runtime never imports ``training``.
"""

from training.data.samples import (
    Crop,
    PatchPairs,
    patch_pairs,
    random_crop,
    random_patch_pairs,
    usable_pixels,
)

__all__ = ["Crop", "PatchPairs", "patch_pairs", "random_crop", "random_patch_pairs", "usable_pixels"]
