"""Feature towers (left.onnx, right.onnx), the model folder manifest that describes them, the
:class:`Towers` protocol the Matcher is written against, and :class:`CachedTowers` for P1/P2 grids."""

from service.features.cache import CachedTowers
from service.features.manifest import (
    ModelError,
    default_model_dir,
    file_entry,
    load_manifest,
    validate_manifest,
    verify_files,
    write_manifest,
)
from service.features.protocol import Towers
from service.features.towers import FeatureTowers

__all__ = [
    "CachedTowers",
    "FeatureTowers",
    "ModelError",
    "Towers",
    "default_model_dir",
    "file_entry",
    "load_manifest",
    "validate_manifest",
    "verify_files",
    "write_manifest",
]
