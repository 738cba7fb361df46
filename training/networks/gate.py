"""A learned per-pixel share between a trained folder's features and a small NCC window (issue 11).

A 3x3 NCC keeps the cost sharp at depth edges and wins on clean, densely textured photographs; the
trained towers win where sensor noise decides a small window's correlation. ``export.hybrid`` blends the
two with one share w for every pixel (or a hand-made w E / (E + E0)); here w is learned per pixel:

    w(x) = sigmoid(a . [F_learned(x), F_ncc(x), log(E(x) + eps)] + b)
    F(x) = [sqrt(1 - w(x)) F_learned(x), sqrt(w(x)) F_ncc(x)]          (unit norm, as every tower's)

so the runtime's unchanged dot product of the two views' features blends the two cosines, each view's
share set by its own window. E is the NCC window's zero-mean energy (its texture); the learned features
tell the gate what surrounds the pixel. Only a and b are trained (``python -m training.gate``), on the
folder's own frozen features, so the gate costs minutes of CPU; ``export.hybrid --gate`` writes the same
operations into the folder's ONNX graph.

>>> import torch
>>> ncc = NCCWindow(3)
>>> features, energy = ncc(torch.rand(1, 3, 20, 30))
>>> features.shape, energy.shape
(torch.Size([1, 8, 20, 30]), torch.Size([1, 1, 20, 30]))
>>> gate = TextureGate(learned_channels=32, window=3)
>>> share = gate(torch.rand(1, 32, 20, 30), features, energy).detach()
>>> float(share.min()) > 0.0 and float(share.max()) < 0.1     # starts nearly closed: the learned cost
True
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

from export.baseline import GREY, MIN_WINDOW, NORM_EPS, ncc_channels, zero_mean_basis

# The gate starts at sigmoid(-3) ~ 0.05: close to the trained folder's own cost, which it must not lose.
INITIAL_GATE_BIAS = -3.0


class NCCWindow(nn.Module):
    """``export.baseline``'s NCC tower in PyTorch: images [N, 3, H, W] -> (features, energy).

    Features [N, w*w - 1, H, W], energy [N, 1, H, W].
    Edge padding by w // 2, the grey (BT.601) window's zero-mean coordinates (one conv), divided by
    sqrt(energy + eps).
    """

    def __init__(self, window: int) -> None:
        super().__init__()
        if window < MIN_WINDOW or window % 2 == 0:
            raise ValueError(f"window must be an odd size from {MIN_WINDOW}, got {window}")
        self.window = window
        kernels = torch.from_numpy(zero_mean_basis(window))[:, None, :] * torch.tensor(GREY)[None, :, None]
        self.register_buffer("unfold", kernels.reshape(ncc_channels(window), 3, window, window).float())

    def forward(self, image: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        radius = self.window // 2
        patches = F.conv2d(F.pad(image, (radius, radius, radius, radius), mode="replicate"), self.unfold)
        energy = (patches * patches).sum(dim=1, keepdim=True)
        return patches / torch.sqrt(energy + NORM_EPS), energy


class TextureGate(nn.Module):
    """The NCC window's share w in (0, 1) per pixel: a 1x1 conv over [learned, NCC, log(E + eps)], sigmoid."""

    def __init__(self, *, learned_channels: int, window: int, bias: float = INITIAL_GATE_BIAS) -> None:
        super().__init__()
        self.learned_channels, self.window = learned_channels, window
        self.conv = nn.Conv2d(learned_channels + ncc_channels(window) + 1, 1, 1)
        nn.init.zeros_(self.conv.weight)
        nn.init.constant_(self.conv.bias, bias)

    def forward(self, learned: torch.Tensor, ncc: torch.Tensor, energy: torch.Tensor) -> torch.Tensor:
        return torch.sigmoid(self.conv(torch.cat([learned, ncc, torch.log(energy + NORM_EPS)], dim=1)))

    def to_dict(self) -> dict[str, object]:
        """The gate as JSON-ready numbers (what ``export.hybrid --gate`` reads)."""
        return {"window": self.window, "learned_channels": self.learned_channels,
                "weight": [float(v) for v in self.conv.weight.detach().flatten()],
                "bias": float(self.conv.bias.detach()[0])}

    @classmethod
    def from_dict(cls, values: dict[str, object]) -> TextureGate:
        gate = cls(learned_channels=int(values["learned_channels"]), window=int(values["window"]))  # type: ignore[call-overload]
        weight = torch.tensor(values["weight"], dtype=torch.float32)
        if weight.numel() != gate.conv.weight.numel():
            raise ValueError(f"the gate has {weight.numel()} weights; {gate.conv.weight.numel()} expected")
        with torch.no_grad():
            gate.conv.weight.copy_(weight.reshape(gate.conv.weight.shape))
            gate.conv.bias.fill_(float(values["bias"]))  # type: ignore[arg-type]
        return gate


def gated_features(learned: torch.Tensor, ncc: torch.Tensor, share: torch.Tensor) -> torch.Tensor:
    """[sqrt(1 - w) F_learned, sqrt(w) F_ncc]: the order and the scaling of ``export.hybrid``'s graph."""
    return torch.cat([torch.sqrt(1.0 - share) * learned, torch.sqrt(share) * ncc], dim=1)
