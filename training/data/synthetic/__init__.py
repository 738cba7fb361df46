"""The synthetic stereo generator: random layered scenes with exact ground truth (NumPy + Pillow).

- ``scene.py``: planar layers in disparity space and their exact two-view ray casting
- ``textures.py``: procedural textures and scikit-image's bundled photos (``training.data.photos``)
- ``photometric.py``: per-view camera effects (blur, gain, gamma, noise, JPEG)
- ``generator.py``: a seed -> a ``service.datasets.StereoSample``; the fixed validation split

The runtime reads the validation split as the dataset SPEC ``synthetic[:N]`` (``synthetic-clean[:N]``:
the same scenes without camera effects; ``synthetic-curved[:N]`` and ``synthetic-fine[:N]``: with the
training levers of those names; ``synthetic-downsampled[:N]``: photographed at 2x and averaged) without
importing ``training``: pyproject.toml registers ``open_validation_split`` and its siblings in the
``adsm.datasets`` entry-point group, which ``service.datasets.open_dataset`` consults
(docs/architecture.md). No torch is imported here.
"""

from .generator import (
    DEFAULT_VALIDATION_COUNT,
    DOWNSAMPLING,
    PHOTO_SHARE,
    VALIDATION_CONFIG,
    VALIDATION_SEED,
    SyntheticConfig,
    SyntheticStereo,
    check_share,
    generate,
    open_clean_validation_split,
    open_curved_validation_split,
    open_downsampled_validation_split,
    open_fine_validation_split,
    open_validation_split,
    other_cameras,
    photograph,
    random_scene,
    render_scene,
    validation_split,
)
from .photometric import Photometric, Rectification, apply_camera

__all__ = ["DEFAULT_VALIDATION_COUNT", "DOWNSAMPLING", "PHOTO_SHARE", "VALIDATION_CONFIG", "VALIDATION_SEED",
           "Photometric", "Rectification",
           "SyntheticConfig", "SyntheticStereo", "apply_camera", "check_share", "generate",
           "open_clean_validation_split", "open_curved_validation_split",
           "open_downsampled_validation_split", "open_fine_validation_split",
           "open_validation_split", "other_cameras", "photograph",
           "random_scene", "render_scene", "validation_split"]
