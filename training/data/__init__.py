"""Training data, built on the runtime's ``service.datasets`` (readers, ``StereoSample``).

- ``samples.py``: patch pairs and dense crops as torch tensors
- ``synthetic/``: the synthetic stereo generator (NumPy + Pillow, no torch)
- ``photos.py``: scikit-image's bundled photographs, found as files

Nothing is imported here, so that ``adsm eval --data synthetic`` loads the generator without torch.
"""
