"""Reproduce one of the paper's result tables (3, 6, 7, 8, 9, 10) on a KITTI copy, with one command.

    python -m training.reproduce --table 6 --data kitti2015:/data/kitti2015 --out runs/table6
    python -m training.reproduce --table 6 ... --launcher torchrun --nproc-per-node 4    (DDP per config)
    python -m training.reproduce --table 6 ... --device cuda --workers 14 --kubernetes-job job.yaml
    python -m training.reproduce --table 6 --data ... --out ... --resume      (continue what is not done)
    python -m training.reproduce --table 6 --data ... --out ... --report      (print the table so far)

The paper's protocol: a 75 % / 25 % random split of the training pairs (seed recorded in OUT/split.json),
one training per config of the table in patch mode (37x37 left patches, 37x237 right strips, batch 128,
40000 iterations, eq. 19's soft label), each exported to ONNX and evaluated on the test part with ONNX
Runtime twice: the network alone (winner-takes-all on the raw volume) and the full pipeline (SGM + check +
fill). The table is printed in the paper's shape with the paper's figures and the differences, and
written to OUT/table.md and OUT/table.json. docs/reproduce.md says what each table measures and what
this reproduction cannot know.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import shlex
import sys
import time
from pathlib import Path

from training.reproduce import kubernetes, report
from training.reproduce.run import PROTOCOL_FILE, Execution, Protocol, run_config, training_command
from training.reproduce.split import check_split, make_split
from training.reproduce.tables import TABLES, get_table


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="python -m training.reproduce",
                                     description=__doc__.split("\n\n")[0],
                                     epilog=__doc__.split("\n\n", 1)[1],
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--table", type=int, required=True, choices=sorted(TABLES))
    parser.add_argument("--data", required=True,
                        help="kitti2015:PATH, kitti2012:PATH (PATH or PATH/training in KITTI's layout) or "
                             "'synthetic' (the project's generator; a dry run of the protocol)")
    parser.add_argument("--out", required=True, type=Path, help="output folder (shared volume on Kubernetes)")
    parser.add_argument("--configs", nargs="+", metavar="NAME",
                        help="a subset of the table's configs (default: every config of the table)")
    parser.add_argument("--iterations", type=int, default=40000, help="per config (paper: %(default)s)")
    parser.add_argument("--batch-size", type=int, default=128,
                        help="patch pairs per step over all processes (paper: %(default)s)")
    parser.add_argument("--channels", type=int, default=64, help="features per tower (paper: %(default)s)")
    parser.add_argument("--separate-towers", action="store_true",
                        help="left and right towers with their own weights (default: shared, Siamese)")
    parser.add_argument("--lr", type=float, default=1e-3, help="Adam learning rate (not in the paper)")
    parser.add_argument("--seed", type=int, default=0, help="trainer seed: examples and initial weights")
    parser.add_argument("--split-seed", type=int, default=0, help="seed of the 75/25 split (recorded)")
    parser.add_argument("--mode", choices=("auto", "patch", "dense"), default="auto",
                        help="trainer mode; auto: patch for 37-pixel configs, dense for Table 7's others "
                             "(the trainer's patch mode cuts 37-pixel patches only)")
    parser.add_argument("--test-pairs", type=int, default=20,
                        help="--data synthetic: pairs of the synthetic validation split to test on")
    parser.add_argument("--resume", action="store_true", help="continue a run in OUT: skip what is done")
    parser.add_argument("--report", action="store_true", help="only print and write the table from OUT")
    parser.add_argument("--index", help="run only the config at this position of --configs ('env': "
                                        "$JOB_COMPLETION_INDEX, as a Kubernetes Indexed Job pod does)")
    parser.add_argument("--launcher", choices=("local", "torchrun"), default="local",
                        help="torchrun: each config trains with DDP over --nproc-per-node processes")
    parser.add_argument("--nproc-per-node", type=int, default=1)
    parser.add_argument("--device", default="cpu", help="trainer device: cpu or cuda[:N]")
    parser.add_argument("--workers", type=int, default=0, help="trainer batch-building processes")
    parser.add_argument("--threads", type=int,
                        help="torch threads per trainer process and ONNX Runtime threads")
    parser.add_argument("--checkpoint-every", type=int, default=1000,
                        help="steps between the trainer's checkpoints (resume points)")
    job = parser.add_argument_group("Kubernetes (write the Indexed Job and exit)")
    job.add_argument("--kubernetes-job", type=Path, metavar="YAML",
                     help="write an Indexed Job with one pod per config to YAML and exit")
    job.add_argument("--image", default=kubernetes.DEFAULT_IMAGE)
    job.add_argument("--claim", default=kubernetes.DEFAULT_CLAIM, help="PersistentVolumeClaim of the volume")
    job.add_argument("--mount", default=kubernetes.DEFAULT_MOUNT, help="where pods mount the claim")
    job.add_argument("--gpus", type=int, default=1, help="GPUs per pod")
    job.add_argument("--cpus", type=int, default=16, help="CPUs requested per pod")
    job.add_argument("--memory-gib", type=int, default=64)
    job.add_argument("--parallelism", type=int, help="pods at once (default: every config)")
    return parser


def protocol_of(args: argparse.Namespace) -> Protocol:
    return Protocol(table=args.table, data=args.data, split_seed=args.split_seed, seed=args.seed,
                    iterations=args.iterations, batch_size=args.batch_size, channels=args.channels,
                    shared=not args.separate_towers, lr=args.lr, mode=args.mode,
                    synthetic_test_pairs=args.test_pairs)


def pod_arguments(args: argparse.Namespace, configs: list[str]) -> list[str]:
    """What every pod of the Kubernetes job runs (after ``python -m training.reproduce``)."""
    words = ["--table", str(args.table), "--data", args.data, "--out", str(args.out), "--configs", *configs,
             "--iterations", str(args.iterations), "--batch-size", str(args.batch_size),
             "--channels", str(args.channels), "--lr", repr(args.lr), "--seed", str(args.seed),
             "--split-seed", str(args.split_seed), "--mode", args.mode, "--test-pairs", str(args.test_pairs),
             "--checkpoint-every", str(args.checkpoint_every),
             "--device", "cuda" if args.device == "cpu" else args.device, "--workers", str(args.workers)]
    if args.separate_towers:
        words.append("--separate-towers")
    if args.launcher == "torchrun":
        words += ["--launcher", "torchrun", "--nproc-per-node", str(args.nproc_per_node)]
    if args.threads:
        words += ["--threads", str(args.threads)]
    return [*words, "--index", "env", "--resume"]


def selected_index(index: str | None, count: int) -> int | None:
    if index is None:
        return None
    value = os.environ.get("JOB_COMPLETION_INDEX") if index == "env" else index
    if value is None or not value.isdigit():
        raise ValueError(f"--index {index}: expected a number or 'env' with JOB_COMPLETION_INDEX set")
    if int(value) >= count:
        raise ValueError(f"--index {value}: only {count} configs")
    return int(value)


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    prog = "training.reproduce"
    table = get_table(args.table)
    configs = args.configs or table.configs
    unknown = [c for c in configs if c not in table.configs]
    if unknown:
        print(f"{prog}: error: not configs of Table {table.number}: {', '.join(unknown)} "
              f"(its configs: {', '.join(table.configs)})", file=sys.stderr)
        return 2
    for name, value in (("iterations", args.iterations), ("batch-size", args.batch_size),
                        ("channels", args.channels), ("test-pairs", args.test_pairs),
                        ("nproc-per-node", args.nproc_per_node), ("checkpoint-every", args.checkpoint_every)):
        if value < 1:
            print(f"{prog}: error: --{name} must be >= 1, got {value}", file=sys.stderr)
            return 2
    for name, value, least in (("gpus", args.gpus, 0), ("cpus", args.cpus, 1),
                               ("memory-gib", args.memory_gib, 1), ("parallelism", args.parallelism, 1),
                               ("threads", args.threads, 1)):
        if value is not None and value < least:
            print(f"{prog}: error: --{name} must be >= {least}, got {value}", file=sys.stderr)
            return 2
    protocol = protocol_of(args)
    if args.kubernetes_job:
        given = sys.argv[1:] if argv is None else argv
        command = shlex.join(["python", "-m", "training.reproduce", *given])
        text = kubernetes.render_job(table=table.number, configs=configs,
                                     pod_args=pod_arguments(args, configs), image=args.image,
                                     claim=args.claim, mount=args.mount, gpus=args.gpus, cpus=args.cpus,
                                     memory_gib=args.memory_gib, parallelism=args.parallelism,
                                     command_line=command)
        try:
            args.kubernetes_job.parent.mkdir(parents=True, exist_ok=True)
            args.kubernetes_job.write_text(text)
        except OSError as error:
            print(f"{prog}: error: {error}", file=sys.stderr)
            return 1
        print(f"wrote {args.kubernetes_job}: Indexed Job {kubernetes.job_name(table.number)}, "
              f"{len(configs)} pods (one per config)")
        return 0
    out: Path = args.out
    try:
        split = check_split(out, args.data, args.split_seed)
        recorded = out / PROTOCOL_FILE
        if args.report:
            if not out.is_dir():
                print(f"{prog}: error: --report: {out} is not a run folder (nothing has run into this --out)",
                      file=sys.stderr)
                return 1
            saved = json.loads(recorded.read_text()) if recorded.is_file() else None
            print(report.write(out, table, split, saved), end="")
            return 0
        if recorded.is_file():
            saved = json.loads(recorded.read_text())
            if saved != dataclasses.asdict(protocol):
                changed = sorted(k for k in saved if saved[k] != dataclasses.asdict(protocol).get(k))
                print(f"{prog}: error: {out} holds a run with another protocol (differs in "
                      f"{', '.join(changed)}); use another --out", file=sys.stderr)
                return 2
            if not args.resume and args.index is None:
                print(f"{prog}: error: {out} already holds a run: pass --resume to continue it",
                      file=sys.stderr)
                return 2
        index = selected_index(args.index, len(configs))
        execution = Execution(launcher=args.launcher, nproc_per_node=args.nproc_per_node, device=args.device,
                              workers=args.workers, threads=args.threads,
                              checkpoint_every=args.checkpoint_every)
        for config in configs:  # a batch that cannot split fails here, before OUT records the protocol
            training_command(protocol, execution, config, "synthetic", out / "runs" / config)
        out.mkdir(parents=True, exist_ok=True)
        split = make_split(args.data, out, seed=args.split_seed, synthetic_test_pairs=args.test_pairs)
        temporary = recorded.with_name(f".{recorded.name}.{os.getpid()}.tmp")
        temporary.write_text(json.dumps(dataclasses.asdict(protocol), indent=1) + "\n")
        os.replace(temporary, recorded)
        todo = configs if index is None else [configs[index]]
        print(f"Table {table.number}: {len(todo)} of {len(configs)} configs, split seed {split['seed']}, "
              f"train {split['train_spec']}, test {split['test_spec']}", flush=True)
        started = time.perf_counter()
        for number, config in enumerate(todo, 1):
            run_config(out, protocol, execution, split, config,
                       log=lambda line, n=number: print(f"[{n}/{len(todo)}] {line}", flush=True))
        print(f"wall time {time.perf_counter() - started:.0f} s\n", flush=True)
        print(report.write(out, table, split, dataclasses.asdict(protocol)), end="")
    except (OSError, ValueError, RuntimeError) as error:
        print(f"{prog}: error: {error}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
