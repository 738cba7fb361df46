"""Left and right towers plus the matching score of eq. (16): the module the trainer optimises.

The towers end in an L2 normalisation (the deployed graph must give bounded costs), so the dot product of
eq. (16) is a cosine in [-1, 1]. A softmax over 201 cosines is almost flat, so the logits of eq. (17)-(18)
are ``temperature * <fl, fr>`` with a learned temperature (docs/networks.md gives the measurement that
chose learned over fixed). The temperature is a training device only: the runtime's cost scale is fixed by
the manifest (``cost.scale``), not derived from it.
"""

from __future__ import annotations

import math

import torch
from torch import nn

from training.networks.configs import get_config
from training.networks.tower import FeatureTower

INITIAL_TEMPERATURE = 3.0  # measured: bench temperature, docs/networks.md


class TowerPair(nn.Module):
    """``.left`` and ``.right`` feature towers (the same module when ``shared``) and a temperature."""

    def __init__(self, config_name: str, *, channels: int = 64, shared: bool = False,
                 standardize_window: int = 0, adaptive_support: bool = False,
                 temperature: float = INITIAL_TEMPERATURE, learn_temperature: bool = True) -> None:
        super().__init__()
        if temperature <= 0:
            raise ValueError(f"temperature must be > 0, got {temperature}")
        self.config = get_config(config_name)
        self.channels = channels
        self.shared = shared
        self.standardize_window = standardize_window
        self.adaptive_support = adaptive_support
        self.left = FeatureTower(self.config, channels=channels, standardize_window=standardize_window,
                                 adaptive_support=adaptive_support)
        self.right = self.left if shared else FeatureTower(self.config, channels=channels,
                                                           standardize_window=standardize_window,
                                                           adaptive_support=adaptive_support)
        # Log-parametrised so that it stays positive and its gradient scales with its size.
        log_t = torch.tensor(math.log(temperature))
        if learn_temperature:
            self.log_temperature = nn.Parameter(log_t)
        else:
            self.register_buffer("log_temperature", log_t)

    @property
    def patch(self) -> int:
        return self.config.patch

    @property
    def receptive_field(self) -> int:
        return self.left.receptive_field

    @property
    def temperature(self) -> float:
        return float(self.log_temperature.detach().exp())

    def spec(self) -> dict[str, object]:
        """What rebuilds this module (stored in checkpoints): config name, channels, sharing, input
        standardisation window (0: none; checkpoints without the key have none), adaptive support (likewise
        off when absent), temperature."""
        return {"config": self.config.name, "channels": self.channels, "shared": self.shared,
                "standardize_window": self.standardize_window, "adaptive_support": self.adaptive_support,
                "learn_temperature": isinstance(self.log_temperature, nn.Parameter)}

    def forward(self, left: torch.Tensor, right: torch.Tensor) -> torch.Tensor:
        """Matching logits ``temperature * <fl, fr>``: left patches [N,3,P,P], right strips [N,3,P,P+K].

        Returns [N, K + 1]: one logit per candidate position along the strip, left to right (the paper:
        P=37, K=200, 201 candidates centred on the true match).
        """
        features_left = self.left(left)
        features_right = self.right(right)
        if features_left.shape[-2:] != (1, 1) or features_right.shape[-2] != 1:
            raise ValueError(f"expected a {self.patch}-pixel-high left patch and right strip, got "
                             f"{tuple(left.shape)} and {tuple(right.shape)}")
        scores = (features_left * features_right).sum(dim=1)  # [N, 1, K + 1]
        return self.log_temperature.exp() * scores[:, 0, :]


def build_tower_pair(config_name: str, *, channels: int = 64, shared: bool = False,
                     standardize_window: int = 0, adaptive_support: bool = False,
                     temperature: float = INITIAL_TEMPERATURE, learn_temperature: bool = True) -> TowerPair:
    """The trainable left/right towers for a named config (see :func:`training.networks.list_configs`);
    ``standardize_window`` k > 0 adds the in-graph local input standardisation, ``adaptive_support`` the
    image-weighted conv taps (docs/networks.md)."""
    return TowerPair(config_name, channels=channels, shared=shared, standardize_window=standardize_window,
                     adaptive_support=adaptive_support, temperature=temperature,
                     learn_temperature=learn_temperature)
