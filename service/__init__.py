"""ADSM stereo runtime: ONNX feature towers -> cost volume -> SGM -> disparity. Imports no torch."""

__version__ = "0.1.0"
