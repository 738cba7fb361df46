"""Feature towers (left.onnx, right.onnx), the model folder manifest that describes them, and the
:class:`Towers` protocol the Matcher is written against."""

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
