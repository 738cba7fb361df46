"""One checkpoint format for the trainer and the exporter, read back with ``torch.load(weights_only=True)``.

A checkpoint is a plain dict of tensors and JSON-like values (no pickled classes), so loading a file from
someone else cannot run code. It holds what rebuilds the model (its spec), the weights, optionally the
optimizer state and RNG states to resume exactly, and what the exporter copies into the manifest:
training provenance, metrics, and deployment settings (input normalisation, SGM penalties, ...).
"""

from __future__ import annotations

import dataclasses
import os
import random
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
import torch

from service.features.defaults import RUNTIME_DEFAULTS
from training.networks import TowerPair, build_tower_pair

FORMAT = "adsm-checkpoint/1"
# Provenance keys the manifest schema requires once a model is trained (see manifest.schema.json).
TRAINING_KEYS = ("command", "data", "wall_time_s", "iterations")
# What save_checkpoint writes and load_checkpoint reads back.
PAYLOAD_KEYS = ("spec", "model", "optimizer", "step", "metrics", "training", "config", "deploy", "rng")


@dataclasses.dataclass(frozen=True, kw_only=True)
class Checkpoint:
    """A loaded checkpoint; :meth:`build_model` turns it back into a :class:`TowerPair`."""

    spec: dict[str, Any]               # TowerPair.spec(): config, channels, shared, learn_temperature
    state_dict: dict[str, torch.Tensor]
    step: int
    metrics: dict[str, Any]            # {data set: {metric: value}}, copied to the manifest
    training: dict[str, Any] | None    # provenance (command, data, wall_time_s...); None: untrained
    config: dict[str, Any]             # the trainer's hyper-parameters, as it chose to record them
    deploy: dict[str, Any]             # manifest settings chosen in training: input, p1, p2, trained_range...
    optimizer: dict[str, Any] | None = None
    rng: dict[str, Any] | None = None

    def build_model(self) -> TowerPair:
        """The model with the saved weights, in eval mode."""
        model = build_tower_pair(self.spec["config"], channels=int(self.spec["channels"]),
                                 shared=bool(self.spec["shared"]),
                                 standardize_window=int(self.spec.get("standardize_window", 0)),
                                 adaptive_support=bool(self.spec.get("adaptive_support", False)),
                                 learn_temperature=bool(self.spec.get("learn_temperature", True)))
        model.load_state_dict(self.state_dict)
        return model.eval()

    def deploy_settings(self) -> dict[str, Any]:
        """``deploy`` over the runtime defaults (``service.features.defaults``), as export and validation
        read it."""
        return RUNTIME_DEFAULTS.deploy(self.deploy)

    def restore_rng(self, generators: Mapping[str, np.random.Generator] | None = None) -> None:
        """Put Python's and torch's global generators, and the named NumPy ``generators``, back where the
        checkpoint left them (the names must be those given to :func:`save_checkpoint`)."""
        if self.rng is None:
            raise ValueError("this checkpoint has no RNG states (saved with rng=False)")
        random.setstate(_tuples(self.rng["python"]))
        torch.set_rng_state(self.rng["torch"])
        saved = self.rng["numpy"]
        for name, generator in (generators or {}).items():
            if name not in saved:
                known = ", ".join(saved) or "none"
                raise ValueError(f"no state for NumPy generator {name!r} (saved: {known})")
            generator.bit_generator.state = saved[name]


def rng_states(generators: Mapping[str, np.random.Generator] | None = None) -> dict[str, Any]:
    """Python's and torch's global RNG states and the states of the named NumPy generators.

    NumPy's legacy global state is not saved: code here draws from explicit ``np.random.Generator``s.
    """
    return {"python": random.getstate(), "torch": torch.get_rng_state(),
            "numpy": {name: g.bit_generator.state for name, g in (generators or {}).items()}}


def save_checkpoint(path: str | os.PathLike[str], *, model: TowerPair, step: int,
                    optimizer: torch.optim.Optimizer | None = None, metrics: Mapping[str, Any] | None = None,
                    training: Mapping[str, Any] | None = None, config: Mapping[str, Any] | None = None,
                    deploy: Mapping[str, Any] | None = None, rng: bool = True,
                    generators: Mapping[str, np.random.Generator] | None = None) -> Path:
    """Write a checkpoint atomically (temp file + rename, so a crash never leaves half a file).

    ``training`` is the provenance the manifest shows (command, data, wall_time_s, iterations and
    optionally device, finished, git_commit); leave it None for an untrained model. ``rng`` saves the
    global RNG states and those of the named NumPy ``generators`` so that training resumes on the same
    random streams (:meth:`Checkpoint.restore_rng`). ``deploy`` holds manifest settings decided in
    training: ``input`` (range, mean, std), ``cost_scale``, ``p1``, ``p2``, ``sgm_tuned_on``,
    ``default_max``, ``trained_range`` (disparities seen in training).
    """
    if step < 0:
        raise ValueError(f"step must be >= 0, got {step}")
    if training is not None and (missing := [k for k in TRAINING_KEYS if k not in training]):
        raise ValueError(f"training provenance lacks {', '.join(missing)}")
    payload = {
        "format": FORMAT,
        "spec": model.spec(),
        "model": model.state_dict(),
        "optimizer": optimizer.state_dict() if optimizer is not None else None,
        "step": int(step),
        "metrics": dict(metrics or {}),
        "training": dict(training) if training is not None else None,
        "config": dict(config or {}),
        "deploy": dict(deploy or {}),
        "rng": rng_states(generators) if rng else None,
    }
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    temporary = path.with_name(path.name + ".tmp")
    torch.save(payload, temporary)
    os.replace(temporary, path)
    return path


def update_checkpoint(path: str | os.PathLike[str], *, metrics: Mapping[str, Any],
                      deploy: Mapping[str, Any]) -> Path:
    """Replace a checkpoint's ``metrics`` and ``deploy`` in place (atomically), keeping everything else:
    weights, optimizer and RNG states (so ``--resume`` still continues it exactly), step, provenance."""
    path = Path(path)
    load_checkpoint(path)  # refuse anything that is not a complete checkpoint
    payload = torch.load(path, map_location="cpu", weights_only=True)
    payload["metrics"], payload["deploy"] = dict(metrics), dict(deploy)
    temporary = path.with_name(path.name + ".tmp")
    torch.save(payload, temporary)
    os.replace(temporary, path)
    return path


def load_checkpoint(path: str | os.PathLike[str]) -> Checkpoint:
    """Read a checkpoint safely (``weights_only=True``); a clear error for anything else."""
    try:
        payload = torch.load(Path(path), map_location="cpu", weights_only=True)
    except FileNotFoundError:
        raise
    except Exception as error:  # torch raises several types for foreign or corrupted files
        raise ValueError(f"{path} is not a readable ADSM checkpoint: {error}") from error
    if not isinstance(payload, dict) or payload.get("format") != FORMAT:
        found = payload.get("format") if isinstance(payload, dict) else type(payload).__name__
        raise ValueError(f"{path} is not an ADSM checkpoint (format {found!r}, expected {FORMAT!r})")
    if missing := [key for key in PAYLOAD_KEYS if key not in payload]:
        raise ValueError(f"{path} is not a complete ADSM checkpoint: it lacks {', '.join(missing)}")
    if not isinstance(payload["spec"], dict) or not isinstance(payload["model"], dict):
        raise ValueError(f"{path} is not a complete ADSM checkpoint: its spec or weights are not mappings")
    return Checkpoint(spec=payload["spec"], state_dict=payload["model"], step=payload["step"],
                      metrics=payload["metrics"], training=payload["training"], config=payload["config"],
                      deploy=payload["deploy"], optimizer=payload["optimizer"], rng=payload["rng"])


def _tuples(value: Any) -> Any:
    """random.setstate needs tuples; a round trip may not preserve them."""
    return tuple(_tuples(v) for v in value) if isinstance(value, list | tuple) else value
