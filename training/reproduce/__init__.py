"""Reproduce the paper's result tables on a user's KITTI copy: ``python -m training.reproduce --help``.

``tables`` (the paper's figures and the config of each row), ``split`` (the seeded 75/25 split),
``run`` (train -> export -> evaluate one config), ``report`` (the table beside the paper's),
``kubernetes`` (an Indexed Job, one pod per config). docs/reproduce.md.
"""
