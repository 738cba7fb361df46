"""The training loop: Adam, scheduled rate, periodic validation through the runtime, last/best checkpoints.

Under ``torchrun`` every process trains on its own examples (see ``batches``) and DistributedDataParallel
(gloo, CPU) averages the gradients; only rank 0 validates, logs and writes checkpoints. The loss of each
step (averaged over processes) goes to ``OUT/history.jsonl``; resuming from ``last.pt`` continues that
file exactly where the interrupted run would have.
"""

from __future__ import annotations

import dataclasses
import json
import os
import time
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import torch
import torch.distributed as dist
from torch.nn.parallel import DistributedDataParallel
from tqdm import tqdm

from service.datasets import open_dataset
from service.features.defaults import RUNTIME_DEFAULTS
from training.allocator import keep_freed_memory
from training.checkpoint import load_checkpoint, save_checkpoint
from training.data.evaluation_only import CONES_NAME, CONES_SPEC
from training.data.synthetic import PHOTO_SHARE
from training.evaluation import runtime_metrics
from training.model_folder import load_start
from training.networks import build_tower_pair, get_config
from training.schedule import DEFAULT_SCHEDULE, learning_rate
from training.sgm_loss import volume_disparities
from training.trainer.batches import DEFAULT_AUGMENTATION, SEED_STRIDE, BatchSpec, TrainingData
from training.trainer.objective import Objective
from training.trainer.prefetch import StepBatches, step_batches
from training.trainer.warm_start import warm_start

SELECTION_METRIC = ("synthetic-validation", "bad2")   # best.pt: lowest synthetic bad-2 (never Cones)


@dataclasses.dataclass(frozen=True, kw_only=True)
class TrainConfig:
    config: str = "37-1deconv5-4conv"
    channels: int = 64
    shared: bool = False
    standardize_window: int = 0         # in-graph local input standardisation (0: raw RGB, as the paper)
    adaptive_support: bool = False      # conv taps weighted by colour likeness to the centre (extension)
    temperature: float = 10.0           # initial softmax temperature (learned afterwards)
    data: str = "synthetic"
    mode: str = "dense"
    iterations: int = 1000
    batch_size: int = 2                 # per process: crops (dense) or patch pairs (patch)
    lr: float = 1e-3
    schedule: str = DEFAULT_SCHEDULE
    weight_decay: float = 0.0
    seed: int = 0
    crop: tuple[int, int] = (128, 256)
    max_disparity: int = 96
    augmentation: str = DEFAULT_AUGMENTATION
    label: str = "paper"                # a key of training.losses.LABELS: eq. (19) on the rounded truth
    edge_weight: float = 0.0            # extra loss weight within 3 px of a depth edge (0: the paper's mean)
    edge_region: str = "both"           # training.losses.EDGE_REGIONS: where edge_weight applies
    sgm_loss: float = 0.0               # share of the loss after SGM (training.sgm_loss); 0: the paper's
    both_views: bool = False            # eq. (18) from the right view too (Objective); False: the paper's
    subpixel_loss: float = 0.0          # weight of |sub-pixel vertex error| per pixel (Objective); 0: paper
    rectification_error: bool = False   # synthetic right views slightly misaligned (batches.BatchSpec)
    vignetting: float = 0.0             # synthetic per-view vignetting strength up to this
    clean_views: float = 0.0            # synthetic: share of pairs without camera effects
    curved_surfaces: float = 0.0        # synthetic: share of objects that bulge towards the cameras
    fine_textures: float = 0.0          # synthetic: share of surfaces painted at twice the frequency
    photo_textures: float = PHOTO_SHARE  # synthetic: share of surfaces painted with a photo
    downsampled_views: float = 0.0      # synthetic: share of scenes photographed at 2x, averaged 2 x 2
    camera_draws: int = 1               # synthetic: examples per rendered scene (fresh cameras each)
    val_every: int = 200
    val_pairs: int = 8
    cones: str = CONES_SPEC             # evaluation only; "" skips it
    out: str = "runs/train"
    threads: int | None = None
    device: str = "cpu"                 # "cuda[:N]" trains on a GPU; validation stays in the runtime
    workers: int = 0                    # processes that build batches ahead (0: in the loop's process)
    init_from: str | None = None        # warm start (weights only, widened if needed); not with resume
    stop_after: int | None = None       # stop (validate + checkpoint) after this step, as if interrupted
    time_budget_s: float | None = None  # likewise, at the first step after this many seconds of this run
    command: str = ""


def _distributed() -> tuple[int, int]:
    if "WORLD_SIZE" in os.environ and int(os.environ["WORLD_SIZE"]) > 1:
        if not dist.is_initialized():
            dist.init_process_group("gloo")
        return dist.get_rank(), dist.get_world_size()
    return 0, 1


def _threads(config: TrainConfig, world: int) -> int:
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
    # Processes share the cores; more threads than cores only adds contention.
    return config.threads or max(1, cores // world)


def train(config: TrainConfig, *, resume: str | None = None) -> dict[str, Any]:
    """Run (or resume) a training; returns a summary (steps, wall time, best validation metrics)."""
    rank, world = _distributed()
    torch.set_num_threads(_threads(config, world))
    keep_freed_memory()  # a dense CPU step otherwise page-faults its volume-sized tensors in every time
    torch.manual_seed(config.seed)
    if config.mode == "patch" and config.batch_size % 4:
        raise ValueError("patch mode takes patch pairs in groups of 4 per batch (batch size % 4 == 0)")
    per_example = config.batch_size // 4 if config.mode == "patch" else 1
    examples_per_step = 4 if config.mode == "patch" else config.batch_size
    if examples_per_step % config.camera_draws:
        raise ValueError(f"--camera-draws {config.camera_draws} must divide the {examples_per_step} "
                         "examples of a step (the batch size; 4 in patch mode), so that a scene's "
                         "examples share a batch and it is rendered once")
    spec = BatchSpec(height=config.crop[0], width=config.crop[1], max_disparity=config.max_disparity,
                     patches_per_pair=per_example, augmentation=config.augmentation,
                     rectification_error=config.rectification_error, vignetting=config.vignetting,
                     clean_views=config.clean_views, curved_surfaces=config.curved_surfaces,
                     fine_textures=config.fine_textures, photo_textures=config.photo_textures,
                     downsampled_views=config.downsampled_views,
                     camera_draws=config.camera_draws,
                     patch=get_config(config.config).patch)
    data = TrainingData(config.data, seed=config.seed, spec=spec)

    device = torch.device(config.device)
    if device.type == "cuda" and not torch.cuda.is_available():
        raise ValueError(f"--device {config.device}: this torch build sees no CUDA device")
    model = build_tower_pair(config.config, channels=config.channels, shared=config.shared,
                             standardize_window=config.standardize_window,
                             adaptive_support=config.adaptive_support,
                             temperature=config.temperature).to(device)
    optimizer = torch.optim.Adam(model.parameters(), lr=config.lr, weight_decay=config.weight_decay)
    out = Path(config.out)
    step, wall_before, best = 0, 0.0, None
    if not resume and (out / "last.pt").exists():  # every rank: none may go on alone into DDP
        # A fresh start would truncate OUT/history.jsonl and overwrite the earlier run's checkpoints.
        raise ValueError(f"{out} already holds a run ({out / 'last.pt'}): continue it with --resume "
                         f"{out / 'last.pt'} (or --resume auto), or write to another --out")
    validation = open_dataset(f"synthetic:{config.val_pairs}")
    cones = open_dataset(config.cones) if config.cones and rank == 0 else None
    if config.init_from and not resume:
        warm_start(model, config.init_from)
    if resume:
        checkpoint = load_checkpoint(resume)
        _check_resumable(checkpoint.spec, model.spec(), resume)
        model.load_state_dict(checkpoint.state_dict)
        if checkpoint.optimizer is None:
            raise ValueError(f"{resume} has no optimizer state: cannot resume exactly")
        optimizer.load_state_dict(checkpoint.optimizer)
        checkpoint.restore_rng()
        step = checkpoint.step
        wall_before = float(checkpoint.training["wall_time_s"]) if checkpoint.training else 0.0
        best = checkpoint.config.get("best")
    objective = Objective(model, mode=config.mode, label=config.label, edge_weight=config.edge_weight,
                          edge_region=config.edge_region, sgm_share=config.sgm_loss,
                          both_views=config.both_views, vertex_weight=config.subpixel_loss,
                          sgm_disparities=volume_disparities(config.max_disparity, config.crop[1]))
    wrapped = DistributedDataParallel(objective) if world > 1 else objective
    history = out / "history.jsonl"
    if rank == 0:
        out.mkdir(parents=True, exist_ok=True)
        _truncate_history(history, step)
    deploy = RUNTIME_DEFAULTS.deploy({"trained_range": data.trained_range})

    started = time.perf_counter()
    bar = tqdm(total=config.iterations, initial=step, disable=rank != 0, dynamic_ncols=True, mininterval=5)
    metrics: dict[str, Any] = {}
    end = min(config.iterations, config.stop_after or config.iterations)
    batches = step_batches(StepBatches(data, mode=config.mode, first=step, end=end, world=world, rank=rank,
                                       examples_per_step=examples_per_step),
                           workers=config.workers, device=device)
    while step < end:
        model.train()
        for group in optimizer.param_groups:
            group["lr"] = learning_rate(step, peak=config.lr, iterations=config.iterations,
                                        schedule=config.schedule)
        tick = time.perf_counter()
        loss, examples = wrapped(*next(batches))
        optimizer.zero_grad(set_to_none=True)
        loss.backward()
        optimizer.step()
        step += 1
        if _out_of_time(config, started, world):
            end = step  # validate and checkpoint this step, as if --stop-after had named it
        mean_loss = float(loss.detach())
        if world > 1:
            summed = torch.tensor([mean_loss, float(examples)], dtype=torch.float64)
            dist.all_reduce(summed)
            mean_loss, examples = float(summed[0]) / world, int(summed[1])
        if rank == 0:
            rate = examples / max(time.perf_counter() - tick, 1e-9)
            bar.set_postfix(loss=f"{mean_loss:.4f}", px_s=f"{rate:.0f}", refresh=False)
            bar.update(1)
            with history.open("a") as log:
                log.write(json.dumps({"step": step, "loss": mean_loss, "examples": examples,
                                      "lr": optimizer.param_groups[0]["lr"]}) + "\n")
        if step % config.val_every == 0 or step == end:
            if rank == 0:
                metrics = {"synthetic-validation": runtime_metrics(model, validation, deploy=deploy)}
                if cones is not None:
                    metrics[CONES_NAME] = runtime_metrics(model, cones, deploy=deploy)
                score = metrics[SELECTION_METRIC[0]][SELECTION_METRIC[1]]
                improved = best is None or score < best
                best = score if improved else best
                wall = wall_before + time.perf_counter() - started
                _save(out, config, model, optimizer, step, metrics, deploy, wall, best, data, improved)
                with (out / "validation.jsonl").open("a") as log:
                    log.write(json.dumps({"step": step, "wall_time_s": round(wall, 1), **metrics}) + "\n")
                bar.write(f"step {step}: synthetic bad-2 {score:.2f} % "
                          f"(best {best:.2f}), cones bad-2 "
                          f"{metrics.get(CONES_NAME, {}).get('bad2')}")
            if world > 1:
                dist.barrier()
    bar.close()
    wall = wall_before + time.perf_counter() - started
    return {"steps": step, "wall_time_s": wall, "best": best, "metrics": metrics}


def _check_resumable(saved: dict[str, Any], mine: dict[str, Any], resume: str) -> None:
    """A resumed run must build the very network the checkpoint holds (its weights load as they are)."""
    keys = ("config", "channels", "shared", "standardize_window", "adaptive_support")
    defaults = {"standardize_window": 0, "adaptive_support": False}  # checkpoints from before the options
    differ = [f"{key} {saved.get(key, defaults.get(key))!r} (this run: {mine[key]!r})" for key in keys
              if saved.get(key, defaults.get(key)) != mine[key]]
    if differ:
        raise ValueError(f"--resume {resume}: the checkpoint's network differs: {', '.join(differ)}; resume "
                         "with its own options, or start from its weights with --init-from")


def _out_of_time(config: TrainConfig, started: float, world: int) -> bool:
    """Whether the run's time budget is spent; under DDP rank 0's clock decides for every process."""
    if config.time_budget_s is None:
        return False
    spent = time.perf_counter() - started > config.time_budget_s
    if world > 1:
        decision = torch.tensor([spent], dtype=torch.int32)
        dist.broadcast(decision, src=0)
        spent = bool(decision.item())
    return spent


def _save(out: Path, config: TrainConfig, model, optimizer, step: int, metrics: dict[str, Any],
          deploy: dict[str, Any], wall: float, best: float, data: TrainingData, improved: bool) -> None:
    training = {"command": config.command, "data": _describe_data(config, data),
                "wall_time_s": round(wall, 1), "iterations": step,
                "device": _describe_device(config)}
    if step >= config.iterations:  # the schedule ran to its end (not stopped early)
        training["finished"] = datetime.now(UTC).isoformat(timespec="seconds")
    if config.init_from:
        training |= warm_start_provenance(config.init_from, wall)
    recorded = {**dataclasses.asdict(config), "best": best, "selection": "/".join(SELECTION_METRIC)}
    save_checkpoint(out / "last.pt", model=model, step=step, optimizer=optimizer, metrics=metrics,
                    training=training, config=recorded, deploy=deploy)
    if improved:
        save_checkpoint(out / "best.pt", model=model, step=step, optimizer=optimizer, metrics=metrics,
                        training=training, config=recorded, deploy=deploy)


def warm_start_provenance(init_from: str, wall: float) -> dict[str, Any]:
    """What a warm-started model owes to its starting checkpoint: the chain of commands, the total time."""
    earlier = load_start(init_from).training or {}
    previous = {key: earlier[key] for key in ("command", "data", "wall_time_s", "iterations", "warm_start",
                                              "model_folder") if key in earlier}
    total = wall + float(earlier.get("wall_time_total_s", earlier.get("wall_time_s", 0.0)))
    return {"warm_start": {"checkpoint": init_from, **previous}, "wall_time_total_s": round(total, 1)}


def _describe_device(config: TrainConfig) -> str:
    device = torch.device(config.device)
    if device.type == "cuda":
        return f"{torch.cuda.get_device_name(device)} ({config.workers} batch workers)"
    return f"cpu ({torch.get_num_threads()} threads)"


def _describe_data(config: TrainConfig, data: TrainingData) -> str:
    if config.data != "synthetic":
        return config.data
    draws = f", {config.camera_draws} camera draws per scene" if config.camera_draws > 1 else ""
    return (f"synthetic (training.data.synthetic.generate, seeds {config.seed * SEED_STRIDE}+, "
            f"{config.crop[0]}x{config.crop[1]}, disparities 0..{config.max_disparity}, "
            f"augmentation {config.augmentation}{draws}); validation: synthetic split, "
            f"{config.val_pairs} pairs")


def _truncate_history(history: Path, step: int) -> None:
    """Keep the logged steps up to ``step`` (a resumed run rewrites what came after its checkpoint)."""
    if not history.exists():
        return
    kept = [line for line in history.read_text().splitlines() if line and json.loads(line)["step"] <= step]
    history.write_text("".join(line + "\n" for line in kept))
