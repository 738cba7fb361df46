"""The loop of ``python -m training.gate``: the NCC share of a folder, learned on its frozen features.

The folder's towers run through ONNX Runtime exactly as deployed (an int8 folder's own int8 features);
only the gate's 1x1 conv (training.networks.gate) and the softmax temperature of the loss learn, on the
synthetic training crops, with the towers' matching loss (eq. 18, optionally weighted near depth edges).
Every ``val_every`` steps the gated features run through the runtime on the synthetic validation split at
the folder's penalties.
"""

from __future__ import annotations

import dataclasses
import json
import math
import time
from pathlib import Path
from typing import Any

import numpy as np
import torch

from export.hybrid import GATE_SCHEMA
from service.datasets import open_dataset
from service.evaluation.evaluate import evaluate
from service.features.towers import FeatureTowers
from service.matcher import Matcher
from training.evaluation import GatedTowers
from training.losses import check_edge_weight, dense_candidates, depth_edge_weights, matching_loss
from training.networks.gate import TextureGate
from training.schedule import learning_rate
from training.trainer.batches import BatchSpec, TrainingData

INITIAL_TEMPERATURE = 20.0  # about what the trainer's towers learn (manifests' training logs): 17-24


@dataclasses.dataclass(frozen=True, kw_only=True)
class GateRun:
    """One gate training: the folder, the NCC window, the schedule and the data (the command's flags)."""

    learned: Path
    out: Path
    window: int = 3
    iterations: int = 1000
    batch_size: int = 4
    lr: float = 5e-3
    edge_weight: float = 0.0
    seed: int = 41
    crop: tuple[int, int] = (128, 256)
    max_disparity: int = 96
    val_every: int = 250
    val_pairs: int = 20
    threads: int = 1


def _uint8(images: torch.Tensor) -> np.ndarray:
    """Crops [B, 3, H, W] in [0, 1] (8-bit values: the generator quantises) -> uint8 [B, H, W, 3]."""
    return (images * 255.0).round().clamp(0, 255).to(torch.uint8).permute(0, 2, 3, 1).numpy()


def train_gate(run: GateRun, *, command: str) -> dict[str, Any]:
    """The training loop (``python -m training.gate``); returns what OUT/gate.json holds."""
    _check(run)
    torch.set_num_threads(run.threads)
    torch.manual_seed(run.seed)
    learned = FeatureTowers(run.learned, threads=run.threads)
    towers = GatedTowers(learned, TextureGate(learned_channels=learned.channels, window=run.window))
    log_temperature = torch.nn.Parameter(torch.tensor(math.log(INITIAL_TEMPERATURE)))
    optimizer = torch.optim.Adam([*towers.gate.parameters(), log_temperature], lr=run.lr)
    spec = BatchSpec(height=run.crop[0], width=run.crop[1], max_disparity=run.max_disparity)
    data = TrainingData("synthetic", seed=run.seed, spec=spec)
    validation = open_dataset(f"synthetic:{run.val_pairs}")
    run.out.mkdir(parents=True, exist_ok=True)
    (run.out / "validation.jsonl").unlink(missing_ok=True)   # an unfinished earlier run's
    validations: list[dict[str, Any]] = []
    started = time.perf_counter()
    for step in range(1, run.iterations + 1):
        for group in optimizer.param_groups:
            group["lr"] = learning_rate(step - 1, peak=run.lr, iterations=run.iterations, schedule="cosine")
        left, right, disparity = data.crops(range((step - 1) * run.batch_size, step * run.batch_size))
        logits, inside, pixels, _ = dense_candidates(*_gated_views(towers, left, right), disparity,
                                                     temperature=log_temperature.exp())
        weights = depth_edge_weights(disparity, pixels, weight=run.edge_weight)
        loss = (weights * matching_loss(logits, inside, reduction="none")).sum() / weights.sum()
        optimizer.zero_grad(set_to_none=True)
        loss.backward()
        optimizer.step()
        if step % run.val_every == 0 or step == run.iterations:
            report = evaluate(Matcher(towers), validation)
            row = {"step": step, "wall_time_s": round(time.perf_counter() - started, 1),
                   "loss": round(float(loss.detach()), 4), f"synthetic:{run.val_pairs}": report["all"]}
            validations.append(row)
            with (run.out / "validation.jsonl").open("a") as log:
                log.write(json.dumps(row) + "\n")
            print(f"step {step}: synthetic:{run.val_pairs} bad-2 {report['all']['bad2']:.2f} %", flush=True)
    files = learned.manifest["files"]
    training = {"command": command, "wall_time_s": round(time.perf_counter() - started, 1),
                "data": f"synthetic crops {run.crop[0]}x{run.crop[1]}, seed {run.seed}, the folder's frozen "
                        "features", "iterations": run.iterations, "batch_size": run.batch_size, "lr": run.lr,
                "edge_weight": run.edge_weight,
                "temperature": round(float(log_temperature.detach().exp()), 3)}
    return {"schema": GATE_SCHEMA, **towers.gate.to_dict(),
            "learned": {"name": learned.manifest["name"],
                        "sha256": {file: entry["sha256"] for file, entry in files.items()}},
            "training": training, "validation": validations}


def _check(run: GateRun) -> None:
    check_edge_weight(run.edge_weight)
    for name in ("iterations", "batch_size", "val_every", "val_pairs", "threads"):
        if getattr(run, name) < 1:
            raise ValueError(f"--{name.replace('_', '-')} must be >= 1, got {getattr(run, name)}")
    if run.window < 1 or run.window % 2 == 0:
        raise ValueError(f"--window must be odd and positive, got {run.window}")
    if (run.out / "gate.json").exists():
        raise ValueError(f"{run.out} already holds a gate ({run.out / 'gate.json'}): write to another --out")


def _gated_views(towers: GatedTowers, left: torch.Tensor, right: torch.Tensor) -> list[torch.Tensor]:
    """Both views' gated features [B, C + w*w, H, W]: the folder's (no gradient), then NCC and the gate."""
    left_u8, right_u8 = _uint8(left), _uint8(right)
    with torch.no_grad():
        pairs = [towers.learned(a, b) for a, b in zip(left_u8, right_u8, strict=True)]
        inputs = [torch.cat([towers.image(crop) for crop in crops]) for crops in (left_u8, right_u8)]
    return [towers.gated(torch.stack([torch.from_numpy(pair[side]) for pair in pairs]), inputs[side])
            for side in (0, 1)]
