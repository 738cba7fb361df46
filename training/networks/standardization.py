"""Local standardisation of a tower's input, inside the graph: each channel's windowed mean and contrast out.

MC-CNN standardises each image before its towers so that the features ignore the gain and bias between
the two cameras. Real rigs also differ locally (vignetting, gamma, per-view exposure), which a per-image
statistic cannot undo, so here every colour channel is standardised over a k x k window, as an NCC window
standardises its pixels:

    z = (x - mean_k(x)) / sqrt(var_k(x) + eps^2)

An affine change of the image (gain and bias, per channel) leaves ``z`` unchanged wherever the window's
contrast is well above ``eps``. The tower receives the image *and* ``z`` (6 channels), so a checkpoint
trained on raw images warm-starts close to its function (the new input channels' weights start near
zero) and the network can still use absolute intensity where a window is flat and ``z`` is mostly noise.

Borders are edge-padded like the tower's own padding, so a dense feature's receptive field grows by
k - 1 pixels (:attr:`FeatureTower.receptive_field`); ``export.to_onnx`` writes the same operations.

>>> import torch
>>> standardize = LocalStandardization(7)
>>> image = torch.rand(1, 3, 20, 30)
>>> standardize(image).shape
torch.Size([1, 6, 20, 30])
>>> gained = 0.8 * image + 0.05                   # another camera's gain and bias
>>> bool(torch.allclose(standardize(gained)[:, 3:], standardize(image)[:, 3:], atol=0.05))
True
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

# Floor of the window's standard deviation, in [0, 1] intensity units: the synthetic generator's largest
# sensor noise (sigma 0.02, docs/data.md), so a window whose contrast is only noise gives |z| of about 1
# or less.
STANDARDIZATION_EPS = 0.02


class LocalStandardization(nn.Module):
    """[N, C, H, W] -> [N, 2C, H, W]: the image, then its per-channel k x k local standardisation."""

    def __init__(self, window: int, *, eps: float = STANDARDIZATION_EPS) -> None:
        super().__init__()
        if window < 3 or window % 2 == 0:
            raise ValueError(f"the standardisation window must be odd and >= 3, got {window}")
        if eps <= 0:
            raise ValueError(f"eps must be > 0, got {eps}")
        self.window = window
        self.eps = eps

    def extra_repr(self) -> str:
        return f"window={self.window}, eps={self.eps}"

    def forward(self, image: torch.Tensor) -> torch.Tensor:
        radius = self.window // 2
        padded = F.pad(image, (radius, radius, radius, radius), mode="replicate")
        mean = F.avg_pool2d(padded, self.window, stride=1)
        mean_of_squares = F.avg_pool2d(padded * padded, self.window, stride=1)
        # E[x^2] - E[x]^2 may dip below 0 by rounding in flat windows.
        variance = torch.relu(mean_of_squares - mean * mean)
        standardized = (image - mean) / torch.sqrt(variance + self.eps * self.eps)
        return torch.cat([image, standardized], dim=1)
