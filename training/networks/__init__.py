"""The paper's network zoo: named tower configs, the tower module, the trainable left/right pair.

>>> import torch
>>> from training.networks import build_tower_pair, dense_features
>>> pair = build_tower_pair("37-1deconv5-4conv", channels=64, shared=False)
>>> pair.left(torch.rand(1, 3, 37, 237)).shape   # valid mode: a 37-pixel patch gives one feature row
torch.Size([1, 64, 1, 201])
>>> dense_features(pair.left.eval(), torch.rand(1, 3, 20, 30)).shape   # same-padded: every pixel
torch.Size([1, 64, 20, 30])
"""

from training.networks.configs import (
    CONFIGS,
    DEFAULT_CONFIG,
    TowerConfig,
    get_config,
    list_configs,
    split_kernels,
)
from training.networks.pair import TowerPair, build_tower_pair
from training.networks.tower import FeatureTower, dense_features, l2_normalize, same_padding

__all__ = [
    "CONFIGS",
    "DEFAULT_CONFIG",
    "FeatureTower",
    "TowerConfig",
    "TowerPair",
    "build_tower_pair",
    "dense_features",
    "get_config",
    "l2_normalize",
    "list_configs",
    "same_padding",
    "split_kernels",
]
