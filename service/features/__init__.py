"""Feature towers (left.onnx, right.onnx) and the model folder manifest that describes them."""

from service.features.manifest import (
    ModelError,
    default_model_dir,
    file_entry,
    load_manifest,
    validate_manifest,
    verify_files,
    write_manifest,
)
from service.features.towers import FeatureTowers

__all__ = [
    "FeatureTowers",
    "ModelError",
    "default_model_dir",
    "file_entry",
    "load_manifest",
    "validate_manifest",
    "verify_files",
    "write_manifest",
]
