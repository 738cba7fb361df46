"""One ADSM feature tower: stride-1 transposed convs, valid convs, L2-normalised features.

Training mode is 'valid': a PxP patch maps to 1x1 and a Px(P+200) strip to 1x201, as in the paper.
Dense inference pads the image by (P - 1) / 2 first (:func:`dense_features`), so H x W is kept; the ONNX
export is this function. For conv-only towers each dense feature equals the tower on the PxP patch around
the pixel; with deconvs it equals the tower on the larger ``receptive_field`` patch (centre output), since
a deconv then sees real neighbours where an isolated patch gives it zeros (docs/networks.md).
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

from training.networks.adaptive_support import adaptive_conv, initial_log_gain, support_weights
from training.networks.configs import TowerConfig
from training.networks.standardization import LocalStandardization

NORM_EPS = 1e-12  # as torch.nn.functional.normalize; the ONNX graph uses the same floor


def l2_normalize(features: torch.Tensor) -> torch.Tensor:
    """Features / max(||features||_C, eps): the last op of every tower, so <fl, fr> is a cosine."""
    squared = (features * features).sum(dim=1, keepdim=True)
    return features / torch.sqrt(squared.clamp_min(NORM_EPS * NORM_EPS))


class FeatureTower(nn.Module):
    """Maps [N, 3, H, W] to L2-normalised features [N, C, H - P + 1, W - P + 1] (P = ``config.patch``).

    BN + ReLU follow every layer but the last; Table 2 puts no ReLU after the deconvs of the 1- and
    2-Deconv rows (``config.deconv_relu``). No layer has a bias: BN supplies the shift, and the paper's
    weight counts (Tables 4, 5) include none, not even for the last layer.

    ``standardize_window`` k > 0 (the project's extension) feeds the first layer the image and its local
    k x k standardisation (:class:`LocalStandardization`, 6 channels); the receptive field grows by k - 1.

    ``adaptive_support`` (the project's extension) weights every conv's taps by their colour likeness to
    the window's centre in the input image, with one learned gain per conv
    (:mod:`training.networks.adaptive_support`); conv-only towers of odd kernels, raw input.
    """

    def __init__(self, config: TowerConfig, *, channels: int = 64, standardize_window: int = 0,
                 adaptive_support: bool = False) -> None:
        super().__init__()
        if channels < 1:
            raise ValueError(f"channels must be >= 1, got {channels}")
        if adaptive_support and (config.deconv_kernels or standardize_window
                                 or any(k % 2 == 0 for k in sum(config.kernel_shapes, ()))):
            raise ValueError(f"adaptive support needs a conv-only tower of odd kernels on the raw image; "
                             f"{config.name}{' with input standardisation' if standardize_window else ''} "
                             "is not")
        self.config = config
        self.channels = channels
        self.standardize_window = standardize_window
        self.adaptive_support = adaptive_support
        self.standardize = LocalStandardization(standardize_window) if standardize_window else None
        layers: list[nn.Module] = []
        in_channels = 6 if self.standardize is not None else 3
        deconvs = len(config.deconv_kernels)
        kernels = [(shape, index < deconvs) for index, shape in enumerate(config.kernel_shapes)]
        for index, (kernel, is_deconv) in enumerate(kernels):
            last = index == len(kernels) - 1
            conv_type = nn.ConvTranspose2d if is_deconv else nn.Conv2d
            layers.append(conv_type(in_channels, channels, kernel, bias=False))
            if not last:
                layers.append(nn.BatchNorm2d(channels))
                if not is_deconv or config.deconv_relu:
                    layers.append(nn.ReLU(inplace=True))
            in_channels = channels
        self.layers = nn.Sequential(*layers)
        if adaptive_support:
            convs = len(config.conv_kernels)
            self.support_log_gain = nn.Parameter(torch.full((convs,), initial_log_gain()))

    @property
    def patch(self) -> int:
        return self.config.patch

    @property
    def patch_shape(self) -> tuple[int, int]:
        """(height, width) of the patch that the valid tower maps to 1x1 (square but for anisotropic rows)."""
        return self.config.patch_shape

    @property
    def receptive_field(self) -> int:
        """The config's dense receptive field, grown by the standardisation window when there is one."""
        return self.config.receptive_field + max(self.standardize_window - 1, 0)

    def forward(self, image: torch.Tensor) -> torch.Tensor:
        if image.ndim != 4 or image.shape[1] != 3:
            raise ValueError(f"expected images [N, 3, H, W], got {tuple(image.shape)}")
        height, width = self.patch_shape
        if image.shape[2] < height or image.shape[3] < width:
            raise ValueError(f"input {tuple(image.shape[2:])} is smaller than the {height}x{width} patch")
        if self.standardize is not None:
            image = self.standardize(image)
        if self.adaptive_support:
            return l2_normalize(self._adaptive_layers(image))
        return l2_normalize(self.layers(image))

    def _adaptive_layers(self, image: torch.Tensor) -> torch.Tensor:
        """``self.layers`` with each conv's taps weighted by the image (valid convs of odd kernels: the
        input of a conv is the image cropped by the kernels' half-sizes before it)."""
        features, row, column, conv = image, 0, 0, 0
        for module in self.layers:
            if not isinstance(module, nn.Conv2d):
                features = module(features)
                continue
            kh, kw = module.kernel_size
            if kh * kw == 1:
                features = module(features)
            else:
                guide = image[:, :, row:row + features.shape[2], column:column + features.shape[3]]
                support = support_weights(guide, (kh, kw), self.support_log_gain[conv].exp())
                features = adaptive_conv(features, module.weight, support)
            row, column, conv = row + kh // 2, column + kw // 2, conv + 1
        return features

    def conv_weight_count(self) -> int:
        """Conv and deconv weights (the count of Tables 4 and 5; BN parameters excluded)."""
        return sum(m.weight.numel() for m in self.modules() if isinstance(m, nn.Conv2d | nn.ConvTranspose2d))


def same_padding(patch_shape: tuple[int, int]) -> tuple[int, int, int, int]:
    """(left, right, top, bottom) padding that makes a valid tower of this (height, width) patch keep
    H x W; odd sides centre exactly."""
    height, width = patch_shape
    top, left = (height - 1) // 2, (width - 1) // 2
    return (left, width - 1 - left, top, height - 1 - top)


def dense_features(tower: FeatureTower, image: torch.Tensor) -> torch.Tensor:
    """Features for every pixel, [N, C, H, W]: replicate-pad by half the patch, then the tower.

    Replicate ('edge') padding extends border texture instead of inventing black bars that would match
    each other across the two views; the exported ONNX graph pads the same way.
    """
    if image.ndim != 4:
        raise ValueError(f"expected images [N, 3, H, W], got {tuple(image.shape)}")
    return tower(F.pad(image, same_padding(tower.patch_shape), mode="replicate"))
