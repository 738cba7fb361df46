"""One config of a table: train (the trainer, in its own process), export (ONNX), evaluate (ONNX Runtime).

Everything a config produces lives under ``OUT``: ``runs/CONFIG/`` (the trainer's checkpoints and logs,
``train.log``), ``models/CONFIG/`` (left.onnx, right.onnx, manifest.json) and ``results/CONFIG.json``
(both evaluations). Each step is skipped when its output is complete, so ``--resume`` (and a restarted
Kubernetes pod) continues where a run stopped: the trainer itself resumes from ``runs/CONFIG/last.pt``
(``--resume auto``) and continues bit-exactly.
"""

from __future__ import annotations

import dataclasses
import json
import os
import platform
import shlex
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from training.networks import get_config

PAPER_PATCH = 37          # the trainer's patch mode cuts 37 x 37 patches and 37 x 237 strips
PROTOCOL_FILE = "protocol.json"
RESULT_SCHEMA = "adsm-reproduce/1"


@dataclasses.dataclass(frozen=True, kw_only=True)
class Protocol:
    """What a table's figures depend on; recorded in OUT/protocol.json and checked on --resume."""

    table: int
    data: str                    # the dataset as given (kitti2015:PATH, kitti2012:PATH, synthetic)
    split_seed: int = 0          # the 75/25 draw
    seed: int = 0                # the trainer's seed (examples and initial weights)
    iterations: int = 40000      # paper, section 4
    batch_size: int = 128        # paper, section 4: patch pairs per step (all processes together)
    channels: int = 64           # paper: 64 features
    shared: bool = True          # Siamese towers (paper, section 3)
    lr: float = 1e-3             # not in the paper: the trainer's Adam default
    mode: str = "auto"           # auto: patch for 37-pixel configs, dense for the others (see mode_of)
    synthetic_test_pairs: int = 20

    def mode_of(self, config: str) -> str:
        """The trainer's ``--mode`` for ``config``: its patch mode cuts 37-pixel patches only, so Table 7's
        29/33/41/45 rows train in dense mode (same loss per pixel, docs/data.md) unless told otherwise."""
        if self.mode != "auto":
            return self.mode
        return "patch" if get_config(config).patch == PAPER_PATCH else "dense"


@dataclasses.dataclass(frozen=True, kw_only=True)
class Execution:
    """How the runs execute; changing it between resumes changes no figure."""

    launcher: str = "local"      # local: one process; torchrun: DDP over --nproc-per-node processes
    nproc_per_node: int = 1
    device: str = "cpu"
    workers: int = 0
    threads: int | None = None
    checkpoint_every: int = 1000  # the trainer's --val-every: how often last.pt is written (resume point)


def training_command(protocol: Protocol, execution: Execution, config: str, train_spec: str,
                     run_dir: Path) -> list[str]:
    """The trainer's command line for one config (under torchrun when the launcher says so)."""
    mode = protocol.mode_of(config)
    world = execution.nproc_per_node if execution.launcher == "torchrun" else 1
    args = ["--config", config, "--data", train_spec, "--mode", mode,
            "--iterations", str(protocol.iterations), "--channels", str(protocol.channels),
            "--lr", repr(protocol.lr), "--seed", str(protocol.seed), "--label", "paper",
            "--val-every", str(min(protocol.iterations, execution.checkpoint_every)), "--val-pairs", "1",
            "--cones", "", "--out", str(run_dir), "--resume", "auto",
            "--device", execution.device, "--workers", str(execution.workers)]
    if mode == "patch":
        if protocol.batch_size % (4 * world):
            raise ValueError(f"batch size {protocol.batch_size} must split into groups of 4 patch pairs per "
                             f"process ({world} processes)")
        args += ["--batch-size", str(protocol.batch_size // world)]
    if protocol.shared:
        args.append("--shared")
    if execution.threads:
        args += ["--threads", str(execution.threads)]
    if execution.launcher == "torchrun":
        return [sys.executable, "-m", "torch.distributed.run", "--standalone",
                "--nproc_per_node", str(world), "-m", "training.train", *args]
    return [sys.executable, "-m", "training.train", *args]


def trained_steps(run_dir: Path) -> int:
    """Steps of ``run_dir/last.pt`` (0 when there is none)."""
    last = run_dir / "last.pt"
    if not last.is_file():
        return 0
    from training.checkpoint import load_checkpoint

    return int(load_checkpoint(last).step)


def run_config(out: Path, protocol: Protocol, execution: Execution, split: dict[str, Any], config: str,
               *, log: Callable[[str], Any] = print) -> dict[str, Any]:
    """Train, export and evaluate ``config`` (each step skipped when already done); returns its result."""
    result_path = out / "results" / f"{config}.json"
    if result_path.is_file():
        result = json.loads(result_path.read_text())
        if result.get("protocol") == dataclasses.asdict(protocol):
            log(f"{config}: done earlier ({result_path})")
            return result
    run_dir = out / "runs" / config
    run_dir.mkdir(parents=True, exist_ok=True)
    command = training_command(protocol, execution, config, split["train_spec"], run_dir)
    started = time.perf_counter()
    steps = trained_steps(run_dir)
    if steps < protocol.iterations:
        log(f"{config}: training ({protocol.mode_of(config)} mode, steps {steps} -> {protocol.iterations}), "
            f"log in {run_dir / 'train.log'}")
        with (run_dir / "train.log").open("a") as train_log:
            train_log.write(f"$ {shlex.join(command)}\n")
            train_log.flush()
            done = subprocess.run(command, stdout=train_log, stderr=subprocess.STDOUT, check=False,
                                  env={**os.environ, "PYTHONUNBUFFERED": "1"})
        if done.returncode != 0:
            tail = (run_dir / "train.log").read_text(errors="replace").splitlines()[-15:]
            raise RuntimeError(f"{config}: the trainer exited with {done.returncode}:\n" + "\n".join(tail))
        steps = trained_steps(run_dir)
        if steps < protocol.iterations:
            raise RuntimeError(f"{config}: the trainer stopped at step {steps} of {protocol.iterations}")
    train_seconds = time.perf_counter() - started

    from training.checkpoint import load_checkpoint

    checkpoint = load_checkpoint(run_dir / "last.pt")
    folder = out / "models" / config
    from export.to_onnx import export_folder

    export_folder(run_dir / "last.pt", folder, command=f"training.reproduce: export of {run_dir / 'last.pt'}")
    log(f"{config}: exported {folder}")
    evaluation = evaluate_folder(folder, split["test_spec"], threads=execution.threads)
    result = {"schema": RESULT_SCHEMA, "config": config, "protocol": dataclasses.asdict(protocol),
              "mode": protocol.mode_of(config), "split_seed": split["seed"], "test": split["test_spec"],
              "training": {"command": shlex.join(command), "steps": checkpoint.step,
                           "wall_time_s": (checkpoint.training or {}).get("wall_time_s"),
                           "device": (checkpoint.training or {}).get("device"),
                           "this_call_s": round(train_seconds, 1)},
              "model": str(folder), **evaluation}
    result_path.parent.mkdir(parents=True, exist_ok=True)
    temporary = result_path.with_name(f".{result_path.name}.{os.getpid()}.tmp")
    temporary.write_text(json.dumps(result, indent=1) + "\n")
    os.replace(temporary, result_path)
    net, full = result["network"]["all"], result["pipeline"]["all"]
    log(f"{config}: network bad-2 {net['bad2']:.2f} %, pipeline bad-2 {full['bad2']:.2f} %, "
        f"{result['pipeline']['seconds_per_pair']:.3f} s/pair")
    return result


def network_only() -> dict[str, bool]:
    """The network alone: winner-takes-all on the raw cost volume, i.e. every post-processing switch of
    MatchOptions off (SGM, sub-pixel fit, check, fill, and any switch the runtime adds later)."""
    from service.matcher import MatchOptions

    return {f.name: False for f in dataclasses.fields(MatchOptions) if isinstance(f.default, bool)}


def evaluate_folder(folder: Path, test_spec: str, *, threads: int | None = None) -> dict[str, Any]:
    """Both evaluations of an exported model folder on the test part, through ONNX Runtime."""
    import onnxruntime

    from service.datasets import open_dataset
    from service.evaluation.evaluate import evaluate
    from service.matcher import Matcher, MatchOptions

    matcher = Matcher.from_folder(folder, threads=threads)
    matcher.warmup()
    test = open_dataset(test_spec)
    reports = {}
    for name, options in (("network", MatchOptions(**network_only())), ("pipeline", MatchOptions())):
        report = evaluate(matcher, test, options=options)
        reports[name] = {key: report[key] for key in ("all", "nonoccluded", "pairs", "seconds_per_pair",
                                                      "stage_seconds", "options")}
    reports["runtime"] = {"engine": f"onnxruntime {onnxruntime.__version__}",
                          "providers": list(matcher.towers.providers),
                          "threads": threads or len(os.sched_getaffinity(0)),
                          "machine": f"{platform.machine()} {platform.processor() or ''}".strip(),
                          "p1": matcher.manifest["sgm"]["p1"], "p2": matcher.manifest["sgm"]["p2"]}
    return reports
