"""The training objective as one module, so that DistributedDataParallel can wrap it.

Dense: both towers run once per crop (edge-padded, as deployed) and every labelled pixel is an example
of eq. (18). Patch: the paper's 37x37 patches against 37x237 strips. Both return (mean loss, examples).
"""

from __future__ import annotations

import torch
from torch import nn

from training.losses import (
    EDGE_RADIUS_PX,
    LABELS,
    check_edge_region,
    check_edge_weight,
    depth_edge_weights,
    labelled_pixels,
    matching_loss,
    pixel_losses,
    right_view_examples,
)
from training.networks import TowerPair, dense_features
from training.sgm_loss import DEFAULT_PENALTIES, aggregated_losses, check_sgm_share


class Objective(nn.Module):
    def __init__(self, model: TowerPair, *, mode: str, label: str = "paper",
                 edge_weight: float = 0.0, edge_region: str = "both", sgm_share: float = 0.0,
                 sgm_disparities: int = 128, sgm_penalties: tuple[float, float] = DEFAULT_PENALTIES,
                 both_views: bool = False, vertex_weight: float = 0.0) -> None:
        super().__init__()
        if mode not in ("dense", "patch"):
            raise ValueError(f"mode must be 'dense' or 'patch', got {mode!r}")
        if label not in LABELS:
            raise ValueError(f"label must be one of {tuple(LABELS)}, got {label!r}")
        if LABELS[label][1] and mode == "patch":
            raise ValueError(f"the {label} label needs the fractional truth of dense crops (--mode dense)")
        if edge_weight and mode == "patch":
            raise ValueError("the depth-edge weight needs the dense ground truth of crops (--mode dense)")
        if mode == "patch" and len(set(model.left.patch_shape)) > 1:
            raise ValueError(f"patch mode cuts square patches; {model.config.name} is anisotropic "
                             "(--mode dense)")
        check_edge_region(edge_region)
        check_edge_weight(edge_weight)
        check_sgm_share(sgm_share)
        if sgm_share and mode == "patch":
            raise ValueError("the loss after SGM needs the dense cost volume of crops (--mode dense)")
        if both_views and (mode == "patch" or sgm_share):
            raise ValueError("the right view's loss needs dense crops (--mode dense) and the raw costs "
                             "(no --sgm-loss)")
        if not 0 <= vertex_weight < float("inf") or (vertex_weight and (mode == "patch" or sgm_share == 1)):
            raise ValueError(f"the sub-pixel vertex weight (--subpixel-loss) must be >= 0 and finite and "
                             f"needs the raw costs of dense crops (--mode dense, --sgm-loss below 1), got "
                             f"{vertex_weight}")
        # The runtime's quadratic sub-pixel fit at the true match, against the fractional truth
        # (training.losses.vertex_errors): a term on what bad-1 reads, which eq. (18) does not see.
        self.vertex_weight = vertex_weight
        # Eq. (18) from the right view too: each seen match also trains the right pixel against the
        # left row, the softmax the runtime's right-view pass and the left-right check rely on.
        self.both_views = both_views
        # The share of the loss taken after SGM (training.sgm_loss), the rest on the raw costs.
        self.sgm_share, self.sgm_disparities, self.sgm_penalties = sgm_share, sgm_disparities, sgm_penalties
        self.model, self.mode, self.label, self.edge_weight = model, mode, label, edge_weight
        # "far" reaches as far as the towers see: half the receptive field (the larger side).
        self.edge_region = edge_region
        self.edge_radius = EDGE_RADIUS_PX if edge_region == "both" else max(model.left.patch_shape) // 2

    def forward(self, left: torch.Tensor, right: torch.Tensor, target: torch.Tensor
                ) -> tuple[torch.Tensor, int]:
        """Dense: ``target`` is the disparity [B, h, w]. Patch: ``target`` is ``inside`` [N, 201]."""
        if self.mode == "patch":
            return matching_loss(self.model(left, right), target), left.shape[0]
        # On a GPU the towers run in bfloat16 (tensor cores; BN and the loss stay float32): 3-4x the
        # steps per second of float32 at no measured cost in validation error (docs/training.md).
        with torch.autocast(left.device.type, dtype=torch.bfloat16, enabled=left.device.type == "cuda"):
            features_left = dense_features(self.model.left, left)
            features_right = dense_features(self.model.right, right)
        features_left, features_right = features_left.float(), features_right.float()
        temperature = self.model.log_temperature.exp()
        pixels, truth, labelled_shift = labelled_pixels(target)
        if pixels.shape[0] == 0:
            # No labelled pixel (possible on a dataset crop): a zero that still touches every weight,
            # so DDP's gradient all-reduce sees the same parameters on every process.
            return (features_left.sum() + features_right.sum()) * 0.0 + temperature * 0.0, 0
        shape, fractional = LABELS[self.label]
        shift = labelled_shift if fractional else None
        # Pixels near depth edges count (1 + edge_weight) times: the weighted mean of eq. (18).
        weights = depth_edge_weights(target, pixels, weight=self.edge_weight, radius=self.edge_radius,
                                     region=self.edge_region) if self.edge_weight else None
        loss = 0.0
        if self.sgm_share < 1:
            losses = pixel_losses(features_left, features_right, pixels, truth, temperature=temperature,
                                  shift=shift, shape=shape, vertex_weight=self.vertex_weight,
                                  fractional_shift=labelled_shift)
            loss = (1 - self.sgm_share) * _mean(losses, weights)
        if self.both_views:
            # The right view's pixels are the left view's of the mirrored, swapped pair; each keeps the
            # weight of the left pixel whose match it is.
            mirrored, right_truth, right_shift, chosen = right_view_examples(
                pixels, truth, labelled_shift, size=(target.shape[0], target.shape[1], target.shape[2]))
            if chosen.numel():
                losses = pixel_losses(features_right.flip(3), features_left.flip(3), mirrored, right_truth,
                                      temperature=temperature, shift=right_shift if fractional else None,
                                      shape=shape, vertex_weight=self.vertex_weight,
                                      fractional_shift=right_shift)
                loss = 0.5 * (loss + _mean(losses, None if weights is None else weights[chosen]))
        if self.sgm_share:
            losses = aggregated_losses(features_left, features_right, pixels, truth, temperature=temperature,
                                       disparities=self.sgm_disparities, penalties=self.sgm_penalties,
                                       shift=shift, shape=shape)
            loss = loss + self.sgm_share * _mean(losses, weights)
        return loss, int(pixels.shape[0])


def _mean(losses: torch.Tensor, weights: torch.Tensor | None) -> torch.Tensor:
    return losses.mean() if weights is None else (weights * losses).sum() / weights.sum()
