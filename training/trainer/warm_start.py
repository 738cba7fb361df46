"""Warm start: initialise a model from a checkpoint's weights, widening channels where the model is wider.

The weights come from a checkpoint file or from a shipped fp32 model folder (``training.model_folder``).

Same shapes are copied. A wider layer (more channels, same kernel) gets the old weights in its first
slots and small random values elsewhere; new BN channels get a small scale, so the wider network starts
close to the narrow one's function (as Net2Net's function-preserving widening) but the new channels can
still grow: with exact zeros their gradients would be zero forever. A checkpoint of raw-image towers
starts a model with input standardisation the same way: its first layer's 3 input channels are the
image's, and the 3 standardised ones start small. Plain towers start towers with adaptive support at the
initial gain (:mod:`training.networks.adaptive_support`), so the image weights apply from the first step.
"""

from __future__ import annotations

import torch

from training.model_folder import load_start
from training.networks import TowerPair

NEW_SCALE = 0.01   # new entries: this fraction of the old entries' spread


def warm_start(model: TowerPair, checkpoint_path: str, *, generator: torch.Generator | None = None) -> None:
    """Load the checkpoint's (or model folder's) weights into ``model`` (same config and sharing; channels
    >= the saved)."""
    checkpoint = load_start(checkpoint_path)
    for key in ("config", "shared"):
        mine = model.spec()[key]
        if checkpoint.spec[key] != mine:
            raise ValueError(f"--init-from {checkpoint_path}: {key} {checkpoint.spec[key]!r} differs from "
                             f"the model's {mine!r}")
    saved_window = int(checkpoint.spec.get("standardize_window", 0))
    if saved_window not in (0, model.standardize_window):
        raise ValueError(f"--init-from {checkpoint_path}: standardisation window {saved_window} differs from "
                         f"the model's {model.standardize_window}")
    if bool(checkpoint.spec.get("adaptive_support", False)) and not model.adaptive_support:
        raise ValueError(f"--init-from {checkpoint_path}: its towers weigh their taps by the image "
                         "(adaptive support); give --adaptive-support")
    if int(checkpoint.spec["channels"]) > model.channels:
        raise ValueError(f"--init-from {checkpoint_path}: {checkpoint.spec['channels']} channels cannot "
                         f"initialise a narrower model ({model.channels})")
    state = model.state_dict()
    widened = {}
    for name, target in state.items():
        if name not in checkpoint.state_dict and name.endswith("support_log_gain"):
            widened[name] = target.clone()  # plain towers gain adaptive support at its initial gain
            continue
        source = checkpoint.state_dict[name]
        if source.shape == target.shape:
            widened[name] = source.clone()
            continue
        if source.ndim != target.ndim or any(s > t for s, t in zip(source.shape, target.shape, strict=True)):
            raise ValueError(f"--init-from {checkpoint_path}: {name} {tuple(source.shape)} does not fit "
                             f"{tuple(target.shape)}")
        if name.endswith("running_var"):
            fresh = torch.ones_like(target)
        elif name.endswith(("running_mean", ".bias")):
            fresh = torch.zeros_like(target)
        else:  # conv weights and BN scales
            spread = float(source.float().std()) if source.numel() > 1 else 1.0
            fresh = torch.randn(target.shape, generator=generator) * (NEW_SCALE * spread)
        fresh[tuple(slice(0, size) for size in source.shape)] = source
        widened[name] = fresh.to(target.dtype)
    model.load_state_dict(widened)
