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

__all__ = [
    "ModelError",
    "default_model_dir",
    "file_entry",
    "load_manifest",
    "validate_manifest",
    "verify_files",
    "write_manifest",
]
