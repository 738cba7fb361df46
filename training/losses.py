"""The paper's matching loss (eq. 18 with the soft label of eq. 19), for patch pairs and for dense crops.

Candidates are in strip order, as :class:`training.networks.TowerPair` returns them: candidate n in
0..200 is the right-image column ``x - round(d_gt) - 100 + n`` (disparity ``round(d_gt) + 100 - n``), so the
truth is always n = 100. Ground truth is rounded to the nearest integer (half up) as in the paper, whose
labels sit on whole pixels; sub-pixel accuracy comes later from the runtime's quadratic fit.

Candidates whose column lies outside the right image are excluded the same way in both modes: their
logit does not enter the softmax and the label is renormalised over the remaining candidates.

Dense mode computes, per image row, every left-right feature product at once (``[B, H, W, W]`` floats:
256 MiB for a 256 x 512 crop), then gathers each labelled pixel's 201 candidates: the towers run once
per crop and every valid pixel is a training example. The trainer takes the same loss in the banded
form of :func:`pixel_losses`, which never gathers the candidates.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F

HALF_RANGE = 100                       # candidates truth - 100 .. truth + 100
CANDIDATES = 2 * HALF_RANGE + 1
SOFT_LABEL = (0.05, 0.2, 0.5, 0.2, 0.05)   # eq. 19 at offsets -2..2 from the truth
# All the mass on the truth: moved to the fractional truth it is the two-tap label of linear interpolation,
# with no reward for similarity one or two pixels off (the project's extension, not the paper's).
SHARP_LABEL = (0.0, 0.0, 1.0, 0.0, 0.0)


def soft_label(*, candidates: int = CANDIDATES, device: torch.device | None = None,
               shape: tuple[float, ...] = SOFT_LABEL) -> torch.Tensor:
    """Eq. (19): 0.5 on the truth (the centre), 0.2 one pixel off, 0.05 two pixels off, 0 elsewhere.

    ``shape`` gives other weights at offsets -2..2 (:data:`SHARP_LABEL`); it must sum to 1.
    """
    if len(shape) != len(SOFT_LABEL) or abs(sum(shape) - 1.0) > 1e-6 or min(shape) < 0:
        raise ValueError(f"a label shape is {len(SOFT_LABEL)} weights >= 0 that sum to 1, got {shape}")
    if candidates % 2 != 1 or candidates < len(SOFT_LABEL):
        raise ValueError(f"candidates must be odd and >= {len(SOFT_LABEL)}, got {candidates}")
    label = torch.zeros(candidates, device=device)
    centre = candidates // 2
    label[centre - 2 : centre + 3] = torch.tensor(shape, device=device)
    return label


# The trainer's --label: (shape at offsets -2..2, centred on the fractional truth?).
LABELS: dict[str, tuple[tuple[float, ...], bool]] = {
    "paper": (SOFT_LABEL, False),      # eq. (19) on the rounded truth
    "subpixel": (SOFT_LABEL, True),    # eq. (19) moved to the fractional truth
    "sharp": (SHARP_LABEL, True),      # the two-tap label of the fractional truth
}


def shifted_label(label: torch.Tensor, shift: torch.Tensor) -> torch.Tensor:
    """Each row of ``label`` [N, K] moved by ``shift`` [N] candidates (|shift| <= 1), by linear
    interpolation between whole-candidate shifts: the label's mass is kept and its centroid moves by
    exactly ``shift``."""
    weight = shift.abs()[:, None].to(label.dtype)
    towards = torch.where(shift[:, None] > 0, label.roll(1, dims=1), label.roll(-1, dims=1))
    return (1.0 - weight) * label + weight * towards


def matching_loss(logits: torch.Tensor, inside: torch.Tensor | None = None, *,
                  reduction: str = "mean", shift: torch.Tensor | None = None,
                  shape: tuple[float, ...] = SOFT_LABEL) -> torch.Tensor:
    """Cross-entropy (eq. 18) of candidate ``logits`` [N, K] against the soft label centred at K // 2.

    ``inside`` [N, K] (bool) marks candidates inside the right image; the others are excluded.
    ``shift`` [N] moves each example's label by a fraction of a candidate (:func:`shifted_label`): the
    sub-pixel variant, centred on the fractional truth instead of the rounded one.
    ``shape``: the label's weights at offsets -2..2 (:func:`soft_label`).
    ``reduction``: "mean" over the N examples, "sum", or "none" (a loss per example).
    """
    if logits.ndim != 2:
        raise ValueError(f"logits must be [N, candidates], got {tuple(logits.shape)}")
    label = soft_label(candidates=logits.shape[1], device=logits.device, shape=shape).expand_as(logits)
    if shift is not None:
        label = shifted_label(label, shift)
    if inside is not None:
        if inside.shape != logits.shape:
            raise ValueError(f"inside {tuple(inside.shape)} does not match logits {tuple(logits.shape)}")
        if not bool(inside[:, logits.shape[1] // 2].all()):
            raise ValueError("the true match of every example must lie inside the right image")
        logits = logits.masked_fill(~inside, float("-inf"))
        label = label * inside
        label = label / label.sum(dim=1, keepdim=True)
    log_probability = F.log_softmax(logits, dim=1)
    # 0 * -inf would be NaN: excluded candidates carry no label, so drop their terms explicitly.
    losses = -(label * log_probability.masked_fill(label == 0, 0.0)).sum(dim=1)
    if reduction == "none":
        return losses
    if reduction == "sum":
        return losses.sum()
    if reduction == "mean":
        return losses.mean()
    raise ValueError(f"reduction must be 'mean', 'sum' or 'none', got {reduction!r}")


def rounded_disparity(disparity: torch.Tensor) -> torch.Tensor:
    """The paper's integer ground truth: round half up (the same rule in patch and dense sampling)."""
    return torch.floor(disparity + 0.5).long()


def dense_candidates(features_left: torch.Tensor, features_right: torch.Tensor, disparity: torch.Tensor,
                     *, temperature: torch.Tensor | float, half_range: int = HALF_RANGE
                     ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """Candidate logits of every pixel with usable ground truth in a crop.

    ``features_*``: [B, C, H, W] (L2-normalised, from the towers run once per crop); ``disparity``:
    [B, H, W] float, NaN where unknown. A pixel is used when its truth is known and its match
    ``x - round(d)`` is inside the crop. Returns logits [M, 2 * half_range + 1] (strip order), the
    ``inside`` mask of the same shape, the used pixels' (b, y, x) indices [M, 3], and each pixel's
    sub-pixel label shift [M] in candidates (``round(d) - d``: a larger disparity is a smaller column).
    """
    if features_left.shape != features_right.shape or features_left.ndim != 4:
        raise ValueError(f"left {tuple(features_left.shape)} and right {tuple(features_right.shape)} "
                         "features must both be [B, C, H, W]")
    batch, _, height, width = features_left.shape
    if disparity.shape != (batch, height, width):
        raise ValueError(f"disparity {tuple(disparity.shape)} must be [B, H, W] = {(batch, height, width)}")
    pixels, truth, shift = labelled_pixels(disparity)
    logits, inside = pixel_candidates(features_left, features_right, pixels, truth, temperature=temperature,
                                      half_range=half_range)
    return logits, inside, pixels, shift


def pixel_candidates(features_left: torch.Tensor, features_right: torch.Tensor, pixels: torch.Tensor,
                     truth: torch.Tensor, *, temperature: torch.Tensor | float, half_range: int = HALF_RANGE
                     ) -> tuple[torch.Tensor, torch.Tensor]:
    """The candidate logits [M, 2 * half_range + 1] (strip order) and ``inside`` mask of the pixels
    ``pixels`` [M, 3] (b, y, x) whose rounded disparities are ``truth`` [M], as :func:`labelled_pixels`
    gives them; :func:`dense_candidates` is this over every labelled pixel of a crop."""
    width = features_left.shape[3]
    b, y, x = pixels.unbind(1)
    # Every left pixel of a row against every right pixel of the same row: [B, H, W, W].
    products = torch.einsum("bchw,bchv->bhwv", features_left, features_right)
    rows = products[b, y, x]                                                  # [M, W]
    offsets = torch.arange(-half_range, half_range + 1, device=pixels.device)
    candidate_columns = (x - truth)[:, None] + offsets[None, :]              # [M, K]
    inside = (candidate_columns >= 0) & (candidate_columns < width)
    scores = rows.gather(1, candidate_columns.clamp(0, width - 1))
    return temperature * scores, inside


def pixel_losses(features_left: torch.Tensor, features_right: torch.Tensor, pixels: torch.Tensor,
                 truth: torch.Tensor, *, temperature: torch.Tensor | float, shift: torch.Tensor | None = None,
                 shape: tuple[float, ...] = SOFT_LABEL, half_range: int = HALF_RANGE,
                 vertex_weight: float = 0.0, fractional_shift: torch.Tensor | None = None) -> torch.Tensor:
    """Eq. (18) per pixel [M]: ``matching_loss(*pixel_candidates(...), shift=shift, shape=shape,
    reduction="none")``, computed without the candidates' [M, 2 * half_range + 1] tensors.

    With the label renormalised over the candidates inside the image, the cross-entropy is
    ``logsumexp(inside logits) - sum(label * logits)``: the first term is a masked log-sum-exp over the
    rows of the ``[B, H, W, W]`` product volume (the candidate band is a mask on each row), the second
    reads the label's few taps. The candidate tensors, their label, mask and softmax (each as large as
    the volume) were most of a CPU step's time; this is the trainer's dense objective
    (``python -m bench training_step`` measures both).

    ``vertex_weight`` w > 0 adds ``w * |vertex error|`` per pixel (:func:`vertex_errors`, the runtime's
    quadratic sub-pixel fit at the true match, against the fractional truth ``round(d) - fractional_shift``;
    the project's extension, not the paper's).
    """
    if half_range < 3:
        raise ValueError(f"the label's taps reach 3 candidates from the truth; half_range {half_range} < 3")
    if not vertex_weight >= 0 or (vertex_weight and fractional_shift is None):
        raise ValueError(f"a vertex weight is >= 0 and needs the fractional shift, got {vertex_weight}")
    batch, _, height, width = features_left.shape
    b, y, x = pixels.unbind(1)
    # The temperature scales one feature map, not the volume: one pass over [B, C, H, W] instead.
    scores = torch.einsum("bchw,bchv->bhwv", features_left * temperature, features_right)
    # Each labelled pixel's band of candidates as a mask on its row: columns within half_range of its
    # true match (the other rows keep a band too, so no row is empty; they are never read).
    # Two comparisons, so no integer tensor of the volume's size is made (8 bytes a cell on a GPU's batch).
    match = torch.zeros(batch, height, width, 1, dtype=torch.long, device=scores.device)
    match[b, y, x, 0] = x - truth
    columns = torch.arange(width, device=scores.device)
    band = (columns >= match - half_range) & (columns <= match + half_range)
    normaliser = torch.logsumexp(scores.masked_fill(~band, float("-inf")), dim=-1)[b, y, x]
    # The label's taps at offsets -3..3 from the true match: eq. (19)'s five, moved by the shift.
    taps = soft_label(candidates=7, device=scores.device, shape=shape).expand(b.shape[0], -1)
    if shift is not None:
        taps = shifted_label(taps, shift)
    # Candidate n is column x - truth - half_range + n, so offset o from the truth is column x - truth + o.
    tap_columns = (x - truth)[:, None] + torch.arange(-3, 4, device=scores.device)[None, :]
    tap_inside = (tap_columns >= 0) & (tap_columns < width)
    taps = taps * tap_inside
    taps = taps / taps.sum(dim=1, keepdim=True)
    tap_scores = scores[b[:, None], y[:, None], x[:, None], tap_columns.clamp(0, width - 1)]
    losses = normaliser - (taps * tap_scores).sum(dim=1)
    if vertex_weight:
        assert fractional_shift is not None
        fitted = tap_inside[:, 2] & tap_inside[:, 4]
        losses = losses + vertex_weight * vertex_errors(tap_scores[:, 2:5], fractional_shift).abs() * fitted
    return losses


def vertex_errors(scores: torch.Tensor, shift: torch.Tensor) -> torch.Tensor:
    """The runtime's sub-pixel estimate minus the fractional truth, in pixels [M], differentiable.

    ``scores`` [M, 3]: similarity at the right columns ``x - round(d) - 1, x - round(d), x - round(d) + 1``
    (disparities ``round(d) + 1, round(d), round(d) - 1``); ``shift`` [M] = ``round(d) - d``. The cost is
    the negated score, and the fit is ``service.refinement.subpixel``'s: the vertex of the parabola
    through the three costs, clamped to +-0.5, none (the rounded truth) where the parabola does not open
    upwards. Bad-1 on real pairs is where the towers trail a 3x3 NCC, and this is the figure it reads.
    """
    if scores.ndim != 2 or scores.shape[1] != 3 or shift.shape != scores.shape[:1]:
        raise ValueError(f"scores must be [M, 3] and shift [M], got {tuple(scores.shape)} and "
                         f"{tuple(shift.shape)}")
    after, centre, before = (-scores).unbind(1)      # costs at d + 1, d, d - 1
    curvature = before - 2.0 * centre + after
    opens_up = curvature > 0
    offset = (before - after) / (2.0 * torch.where(opens_up, curvature, torch.ones_like(curvature)))
    offset = torch.where(opens_up, offset.clamp(-0.5, 0.5), torch.zeros_like(offset))
    return offset + shift.to(offset.dtype)


def right_view_examples(pixels: torch.Tensor, truth: torch.Tensor, shift: torch.Tensor, *,
                        size: tuple[int, int, int]) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor,
                                                             torch.Tensor]:
    """The labelled left pixels as examples of the right view, mirrored for :func:`pixel_losses`.

    A left pixel (b, y, x) with rounded truth t that the right view sees gives the right pixel
    u = x - t, whose true match is left column x. The right view of a crop mirrored left-right is the
    left view of a rectified pair (the mirrored right image on the left), so the right pixel's loss is
    :func:`pixel_losses` of ``flip(features_right)`` against ``flip(features_left)`` at column
    ``width - 1 - u`` with the same truth and shift (``round(d) - d``: the mirror reverses both the
    columns and the direction in which a larger disparity moves the match).

    Left pixels the right view does not see carry no right example: of the left pixels whose match is
    one right pixel, only the nearest (the largest truth) is seen, and a right pixel between two taken
    by a surface more than a pixel nearer is dropped too (a slanted nearer surface, stretched in the
    right view, leaves a column between its rounded matches that the hidden background claims).
    ``size`` is the crop's (B, H, W), as :func:`labelled_pixels` saw it. Returns the mirrored (b, y, x)
    [N, 3], truth [N], shift [N] and the chosen rows of ``pixels`` [N].
    """
    batch, height, width = size
    b, y, x = pixels.unbind(1)
    column = x - truth
    key = (b * height + y) * width + column
    # Per right pixel, the largest truth among the left pixels that match it (-1: none does).
    nearest = torch.full((batch * height * width,), -1, dtype=truth.dtype, device=truth.device)
    nearest.scatter_reduce_(0, key, truth, reduce="amax")
    seen = truth == nearest[key]
    inside_gap = torch.ones_like(seen)
    for side in (-1, 1):
        neighbour = column + side
        inside = (neighbour >= 0) & (neighbour < width)
        beside = torch.where(inside, nearest[(key + side).clamp(0, nearest.numel() - 1)], -1)
        inside_gap &= beside > truth + 1
    seen &= ~inside_gap
    chosen = seen.nonzero(as_tuple=True)[0]
    mirrored = torch.stack([b[chosen], y[chosen], width - 1 - column[chosen]], dim=1)
    return mirrored, truth[chosen], shift[chosen], chosen


def labelled_pixels(disparity: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """The pixels of ``disparity`` [B, H, W] (NaN unknown) that are training examples: truth known and
    the match ``x - round(d)`` inside the crop. Returns their (b, y, x) [M, 3], rounded truth [M] and
    sub-pixel label shift [M] in candidates (``round(d) - d``)."""
    _, _, width = disparity.shape
    known = torch.isfinite(disparity)
    truth = rounded_disparity(torch.where(known, disparity, torch.zeros_like(disparity)))
    match = torch.arange(width, device=disparity.device) - truth
    b, y, x = (known & (match >= 0) & (match < width)).nonzero(as_tuple=True)
    shift = (truth[b, y, x] - disparity[b, y, x]).float()
    return torch.stack([b, y, x], dim=1), truth[b, y, x], shift


# A ground-truth disparity jump: neighbours more than this far apart (as the eval breakdown counts them).
JUMP_PX = 2.0


def check_edge_weight(weight: float) -> None:
    """Refuse a depth-edge weight that is negative or not finite (NaN would make every loss NaN)."""
    if not 0 <= weight < float("inf"):
        raise ValueError(f"the depth-edge weight must be >= 0 and finite, got {weight}")


# Where the depth-edge weight applies: "both" sides of an edge within EDGE_RADIUS_PX, or the "far" side
# only, out to the tower's reach (the background pixels whose window a nearer surface enters).
EDGE_REGIONS = ("both", "far")
EDGE_RADIUS_PX = 3


def check_edge_region(region: str) -> None:
    """Refuse a depth-edge region that is not one of :data:`EDGE_REGIONS`."""
    if region not in EDGE_REGIONS:
        raise ValueError(f"edge_region must be one of {EDGE_REGIONS}, got {region!r}")


def depth_edge_weights(disparity: torch.Tensor, pixels: torch.Tensor, *, weight: float,
                       radius: int = EDGE_RADIUS_PX, region: str = "both") -> torch.Tensor:
    """Per-example loss weights [M]: ``1 + weight`` on the pixels of ``region``, else 1.

    ``disparity`` [B, H, W] (NaN unknown), ``pixels`` [M, 3] the (b, y, x) of the examples, as
    :func:`dense_candidates` returns them. ``region="both"``: within ``radius`` px of a depth edge, a
    labelled pixel whose 4-neighbour is labelled and more than ``JUMP_PX`` away, or is not labelled (an
    occlusion or the end of the ground truth): the pixels where a wide receptive field fattens the
    foreground, which a plain mean under-weights (they are a few percent of a crop). ``region="far"``:
    only the labelled pixels with a surface more than ``JUMP_PX`` nearer within ``radius`` px (a square
    window), the side that fattening wrongs; pass the tower's half receptive field as ``radius``.
    """
    check_edge_weight(weight)
    check_edge_region(region)
    known = torch.isfinite(disparity)
    value = torch.where(known, disparity, torch.zeros_like(disparity))
    if region == "far":
        labelled = torch.where(known, disparity, torch.full_like(disparity, -torch.inf))
        nearest = F.max_pool2d(labelled[:, None], 2 * radius + 1, stride=1, padding=radius)[:, 0]
        near = known & (nearest > value + JUMP_PX)
    else:
        edge = torch.zeros_like(known)
        for dim in (1, 2):
            a, b = known.narrow(dim, 0, known.shape[dim] - 1), known.narrow(dim, 1, known.shape[dim] - 1)
            gap = (value.narrow(dim, 0, value.shape[dim] - 1)
                   - value.narrow(dim, 1, value.shape[dim] - 1)).abs()
            step = (a != b) | (a & b & (gap > JUMP_PX))
            edge.narrow(dim, 0, edge.shape[dim] - 1).logical_or_(step)
            edge.narrow(dim, 1, edge.shape[dim] - 1).logical_or_(step)
        near = F.max_pool2d(edge[:, None].float(), 2 * radius + 1, stride=1, padding=radius)[:, 0] > 0
    b, y, x = pixels.unbind(1)
    return 1.0 + weight * near[b, y, x].float()


def dense_matching_loss(features_left: torch.Tensor, features_right: torch.Tensor, disparity: torch.Tensor,
                        *, temperature: torch.Tensor | float, reduction: str = "mean") -> torch.Tensor:
    """:func:`matching_loss` over every usable pixel of a crop (see :func:`dense_candidates`)."""
    logits, inside, _, _ = dense_candidates(features_left, features_right, disparity,
                                            temperature=temperature)
    if logits.shape[0] == 0:
        raise ValueError("no pixel of the crop has usable ground truth")
    return matching_loss(logits, inside, reduction=reduction)
