"""Checkpoint -> left.onnx + right.onnx + manifest.json (+ int8 variants)."""
