"""The matching loss after semi-global aggregation: eq. (18) on the costs that SGM leaves, not the raw ones.

The paper's loss scores each pixel's raw feature products alone, so a tower earns its loss only by
resolving every pixel by itself: in flat and repeated paint it must see far, and a far-seeing window
fattens the nearer surface at depth edges. At run time SGM resolves much of that ambiguity, so the
per-pixel loss asks the towers for context that the aggregation would give anyway. Here the crop's cost
volume is built as the runtime builds it (``-scale * <FL, FR>``, ``+scale`` left of the right image),
aggregated along the four SGM paths with constant penalties (:mod:`training.sgm_paths`: hard minima, the
gradient follows the winning path, as in SGM-Net), and the loss is eq. (18) over each labelled pixel's
aggregated costs: what SGM already gets right costs nothing, and the gradient falls where it fails.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F

from service.features.defaults import RUNTIME_DEFAULTS
from training.losses import SOFT_LABEL, shifted_label, soft_label
from training.sgm_paths import PATHS, sgm_paths

COST_SCALE = RUNTIME_DEFAULTS.cost_scale   # the exported manifests' cost.scale
# Penalties on that scale: adsm-rf11's P1/P2, the rule's choice for the 11-px tower.
DEFAULT_PENALTIES = (20.0, 360.0)


def cost_volume(features_left: torch.Tensor, features_right: torch.Tensor, *, disparities: int
                ) -> torch.Tensor:
    """``-COST_SCALE * <FL[:, y, x], FR[:, y, x - d]>`` as [B, H, W, D]; ``+COST_SCALE`` where x - d < 0.

    The features are L2-normalised [B, C, H, W] (the towers' output), so costs lie in +-COST_SCALE.
    """
    batch, _, height, width = features_left.shape
    products = torch.einsum("bchw,bchv->bhwv", features_left, features_right)      # [B, H, W, W]
    columns = torch.arange(width, device=products.device)[:, None] - \
        torch.arange(disparities, device=products.device)[None, :]                  # [W, D]
    scores = products.gather(3, columns.clamp(min=0).expand(batch, height, width, disparities))
    return torch.where(columns >= 0, -COST_SCALE * scores, torch.full_like(scores, COST_SCALE))


def aggregated_losses(features_left: torch.Tensor, features_right: torch.Tensor, pixels: torch.Tensor,
                      truth: torch.Tensor, *, temperature: torch.Tensor | float, disparities: int,
                      penalties: tuple[float, float] = DEFAULT_PENALTIES,
                      shift: torch.Tensor | None = None, shape: tuple[float, ...] = SOFT_LABEL
                      ) -> torch.Tensor:
    """Eq. (18) per example [M] over the aggregated costs of every disparity 0..disparities - 1.

    ``pixels`` [M, 3] are the (b, y, x) of the examples and ``truth`` [M] their rounded disparities, each
    below ``disparities``; ``shift`` and ``shape`` place the label as :func:`training.losses.matching_loss`
    does (label taps outside the volume are dropped and the rest renormalised). The logits are the
    aggregated costs in the raw scores' units (divided by ``COST_SCALE * PATHS``) times the towers'
    temperature, so both losses share one temperature.
    """
    if bool((truth >= disparities).any()) or bool((truth < 0).any()):
        raise ValueError(f"every example's disparity must lie in 0..{disparities - 1}")
    aggregated = sgm_paths(cost_volume(features_left, features_right, disparities=disparities),
                           p1=penalties[0], p2=penalties[1])
    log_probability = F.log_softmax(aggregated * (-temperature / (COST_SCALE * PATHS)), dim=3)
    # The label's taps, one wider on each side so that a sub-pixel shift keeps all its mass.
    taps = len(shape) // 2 + 1
    label = soft_label(candidates=2 * taps + 1, device=truth.device, shape=shape).expand(len(truth), -1)
    if shift is not None:
        label = shifted_label(label, shift)
    # Strip order (training.losses): tap n is the disparity truth + taps - n.
    candidate = truth[:, None] + torch.arange(taps, -taps - 1, -1, device=truth.device)[None, :]
    inside = (candidate >= 0) & (candidate < disparities)
    label = label * inside
    label = label / label.sum(dim=1, keepdim=True)
    b, y, x = pixels.unbind(1)
    chosen = log_probability[b[:, None], y[:, None], x[:, None], candidate.clamp(0, disparities - 1)]
    return -(label * chosen.masked_fill(label == 0, 0.0)).sum(dim=1)


def check_sgm_share(share: float) -> None:
    """Refuse a share of the loss after SGM outside 0..1 (NaN included)."""
    if not 0 <= share <= 1:
        raise ValueError(f"the share of the loss after SGM must be in 0..1, got {share}")


def volume_disparities(max_disparity: int, width: int) -> int:
    """The cost volume's depth for crops of training disparities up to ``max_disparity``: a third more,
    as the runtime's default 128 is over the 96 px the towers are trained on, within the crop."""
    return min(width, max_disparity * 4 // 3)
