"""Train ADSM feature towers.

    python -m training.train --config 37-1deconv5-4conv --data synthetic --channels 16 --out runs/fast
    python -m training.train ... --device cuda --workers 14 --time-budget 540 --resume auto   (GPU chunks)
    torchrun --nproc_per_node 2 -m training.train ...        (DDP over gloo; --batch-size is per process)

Writes OUT/last.pt (every validation), OUT/best.pt (lowest synthetic validation bad-2), OUT/history.jsonl
(loss per step) and OUT/validation.jsonl. ``--resume OUT/last.pt`` continues exactly. Export with
``python -m export.to_onnx --checkpoint OUT/best.pt --out DIR --int8``; tune P1/P2 first with
``python -m training.validate --checkpoint OUT/best.pt --tune``.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import shlex
import sys
from pathlib import Path

import torch

from training.data.evaluation_only import CONES_SPEC
from training.data.synthetic import PHOTO_SHARE
from training.losses import EDGE_REGIONS, LABELS
from training.networks import DEFAULT_CONFIG, build_tower_pair, list_configs
from training.schedule import DEFAULT_SCHEDULE, SCHEDULES
from training.trainer import TrainConfig, train
from training.trainer.batches import AUGMENTATIONS, DEFAULT_AUGMENTATION

# Paper defaults for patch mode (section 4: batch 128, 40000 iterations); dense defaults measured here.
MODE_DEFAULTS = {"patch": {"iterations": 40000, "batch_size": 128},
                 "dense": {"iterations": 3000, "batch_size": 2}}


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="python -m training.train", description=__doc__.split("\n\n")[0],
                                     epilog=__doc__.split("\n\n", 1)[1],
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--config", default=DEFAULT_CONFIG, choices=list_configs(), metavar="NAME",
                        help="network config (default: %(default)s)")
    parser.add_argument("--data", default="synthetic",
                        help="'synthetic' or a dataset SPEC (kitti2015:PATH, kitti2012:PATH, "
                             "middlebury:PATH)")
    parser.add_argument("--mode", choices=("dense", "patch"), default="dense")
    parser.add_argument("--iterations", type=int, help="optimizer steps (dense 3000, patch 40000)")
    parser.add_argument("--batch-size", type=int, help="per process: crops (dense, 2) or patch pairs (128)")
    parser.add_argument("--channels", type=int, default=64)
    parser.add_argument("--shared", action="store_true",
                        help="one tower for both views (converges far faster: docs/training.md)")
    parser.add_argument("--standardize-window", type=int, default=0, metavar="K",
                        help="feed the towers the image and its local KxK standardisation (odd K >= 3; "
                             "0, the default: the raw image, as the paper; docs/networks.md)")
    parser.add_argument("--adaptive-support", action="store_true",
                        help="weight every conv's taps by their colour likeness to the window's centre, "
                             "one learned gain per conv (conv-only towers of odd kernels, such as 11-5conv: "
                             "docs/networks.md)")
    parser.add_argument("--temperature", type=float, default=10.0,
                        help="initial softmax temperature of the cosine logits (learned afterwards)")
    parser.add_argument("--out", default="runs/train")
    parser.add_argument("--resume", help="checkpoint (OUT/last.pt) to continue exactly; 'auto': "
                                         "OUT/last.pt if it exists, else a fresh start (one command "
                                         "for every chunk)")
    parser.add_argument("--seed", type=int, default=0, help="0..99: picks the training examples and init")
    parser.add_argument("--lr", type=float, default=1e-3, help="peak Adam learning rate")
    parser.add_argument("--schedule", choices=SCHEDULES, default=DEFAULT_SCHEDULE,
                        help="learning rate: constant, or 2 %% warm-up then cosine decay to 5 %% "
                             "(default chosen by measurement: docs/training.md)")
    parser.add_argument("--crop", type=int, nargs=2, default=(128, 256), metavar=("H", "W"))
    parser.add_argument("--max-disparity", type=int, default=96, help="synthetic scenes' nearest disparity")
    parser.add_argument("--augmentation", choices=AUGMENTATIONS, default=DEFAULT_AUGMENTATION,
                        help="on top of the generator's camera effects (default chosen by measurement: "
                             "docs/training.md)")
    parser.add_argument("--label", choices=tuple(LABELS), default="paper",
                        help="paper: eq. (19) around the rounded truth; subpixel: the same label moved "
                             "to the fractional truth; sharp: all the mass on the fractional truth, split "
                             "between its two whole pixels (dense mode; docs/training.md)")
    parser.add_argument("--edge-weight", type=float, default=0.0, metavar="W",
                        help="dense mode: pixels within 3 px of a depth edge weigh 1 + W in the loss "
                             "(default 0: the paper's plain mean)")
    parser.add_argument("--edge-region", choices=EDGE_REGIONS, default="both",
                        help="where --edge-weight applies: both sides of a depth edge within 3 px, or the "
                             "far side only, out to half the towers' receptive field (the background pixels "
                             "a nearer surface's fattening reaches; docs/training.md)")
    parser.add_argument("--sgm-loss", type=float, default=0.0, metavar="SHARE",
                        help="dense mode: take this share (0-1) of the loss on the costs after four-path SGM "
                             "at adsm-rf11's penalties (training.sgm_loss), the rest on the raw costs as the "
                             "paper does; default 0")
    parser.add_argument("--both-views", action="store_true",
                        help="dense mode: eq. (18) from the right view too: every match the right view "
                             "sees also trains its right pixel against the left row (the loss the mean of "
                             "both views'; default: the left view's only, as the paper)")
    parser.add_argument("--subpixel-loss", type=float, default=0.0, metavar="W",
                        help="dense mode: add W x |the runtime's quadratic sub-pixel fit at the true match "
                             "minus the fractional truth| (pixels) to each pixel's loss (default 0: the "
                             "paper's; docs/training.md)")
    parser.add_argument("--rectification-error", action="store_true",
                        help="synthetic data: misalign each right view vertically by up to ~1 px (shift, "
                             "rotation, scale: training.data.synthetic.Rectification)")
    parser.add_argument("--vignetting", type=float, default=0.0, metavar="K",
                        help="synthetic data: per-view radial fall-off 1 - k r^2, k drawn from [0, K] "
                             "(default 0)")
    parser.add_argument("--clean-views", type=float, default=0.0, metavar="P",
                        help="synthetic data: render this share of the pairs without camera effects (no "
                             "noise, blur, gain, gamma or JPEG; 8-bit only), so the towers also see views "
                             "whose fine texture is signal (default 0; docs/training.md)")
    parser.add_argument("--curved-surfaces", type=float, default=0.0, metavar="P",
                        help="synthetic data: this share of the objects bulge towards the cameras (a "
                             "paraboloid in disparity) and are shaded as matte solids; the rest of each "
                             "scene stays that of a run without it (default 0; docs/data.md)")
    parser.add_argument("--fine-textures", type=float, default=0.0, metavar="P",
                        help="synthetic data: paint this share of the surfaces at twice the spatial "
                             "frequency (finer detail, as real photographs have); the rest of each scene "
                             "stays that of a run without it (default 0; docs/data.md)")
    parser.add_argument("--photo-textures", type=float, default=PHOTO_SHARE, metavar="P",
                        help="synthetic data: paint this share of the surfaces with one of the bundled "
                             f"photos instead of a procedural texture (default {PHOTO_SHARE}, the "
                             "validation split's share; docs/data.md)")
    parser.add_argument("--downsampled-views", type=float, default=0.0, metavar="P",
                        help="synthetic data: render and photograph this share of the scenes at twice the "
                             "size, then average 2 x 2 (a downsampled photograph, as the real evaluation "
                             "pairs are: finer scenes, anti-aliased edges, half the noise; default 0; "
                             "docs/data.md)")
    parser.add_argument("--camera-draws", type=int, default=1, metavar="K",
                        help="synthetic data: render each scene once and take it with K freshly drawn "
                             "cameras (K consecutive examples; K divides the batch size): ~2.4x the "
                             "examples per second at K 4 where generating pairs bounds the speed, as on a "
                             "GPU, but less learned per step (default 1: every example its own scene; "
                             "docs/training.md, 'Camera draws per scene')")
    parser.add_argument("--val-every", type=int, default=200)
    parser.add_argument("--val-pairs", type=int, default=8, help="synthetic validation pairs per validation")
    parser.add_argument("--cones", default=CONES_SPEC, help="evaluation-only real pair SPEC ('' to skip)")
    parser.add_argument("--init-from", metavar="CKPT",
                        help="start from these weights: a checkpoint, or a shipped fp32 model folder such as "
                             "service/models/adsm-rf11 (same config; more channels are filled in), with a "
                             "fresh optimizer and schedule")
    parser.add_argument("--stop-after", type=int, metavar="STEP",
                        help="stop after this step (checkpoint written) without changing the schedule of "
                             "--iterations: a time-bounded run that --resume can continue")
    parser.add_argument("--time-budget", type=float, metavar="SECONDS",
                        help="stop (validated and checkpointed) at the first step after this many seconds; "
                             "--resume continues: chunks that fit a time-limited machine")
    parser.add_argument("--threads", type=int, help="torch threads per process (default: cores / processes)")
    parser.add_argument("--device", default="cpu",
                        help="cpu (default) or cuda[:N]; training on a GPU: docs/training.md, 'GPU recipe'")
    parser.add_argument("--workers", type=int, default=0,
                        help="processes that build batches ahead of the optimizer (0: none); on a GPU "
                             "generating synthetic pairs is the bottleneck, so use most of the cores")
    return parser


def recorded_command(argv: list[str], args: argparse.Namespace) -> str:
    """The command stored with the checkpoint, naming the values of the defaults chosen by measurement.

    Those defaults may change after a later measurement; a command that names them still reproduces
    the run. ``recorded_command(["--iterations", "9"], parse(...))`` ->
    ``python -m training.train --iterations 9 --schedule constant --augmentation none``.
    """
    given = list(argv)
    for flag, value in (("--schedule", args.schedule), ("--augmentation", args.augmentation)):
        if not any(word == flag or word.startswith(flag + "=") for word in given):
            given += [flag, value]
    return shlex.join(["python", "-m", "training.train", *given])


def resolve_resume(resume: str | None, out: str) -> str | None:
    """``--resume auto`` -> OUT/last.pt when an earlier chunk wrote it, else None (start afresh)."""
    if resume != "auto":
        return resume
    last = Path(out) / "last.pt"
    return str(last) if last.exists() else None


def argument_problem(args: argparse.Namespace) -> str | None:
    """What is wrong with the parsed arguments (one line), or None; checked before anything is written."""
    for name, value in (("iterations", args.iterations), ("batch-size", args.batch_size),
                        ("channels", args.channels), ("val-every", args.val_every),
                        ("val-pairs", args.val_pairs), ("threads", args.threads),
                        ("stop-after", args.stop_after), ("camera-draws", args.camera_draws)):
        if value is not None and value < 1:
            return f"--{name} must be >= 1, got {value}"
    if args.workers < 0:
        return f"--workers must be >= 0, got {args.workers}"
    if args.adaptive_support:
        try:
            build_tower_pair(args.config, channels=1, standardize_window=args.standardize_window,
                             adaptive_support=True)
        except (KeyError, ValueError) as error:
            return f"--adaptive-support: {error}"
    if args.edge_region != "both" and not args.edge_weight:
        return f"--edge-region {args.edge_region} only says where --edge-weight applies; give a weight > 0"
    # (--edge-weight, --vignetting, --clean-views, --curved-surfaces, --fine-textures, --photo-textures
    # and --downsampled-views are checked where they are used, NaN included.)
    floats = (("lr", args.lr, True), ("temperature", args.temperature, True),
              ("time-budget", args.time_budget, False))
    for name, value, positive in floats:
        if value is not None and not (math.isfinite(value) and (value > 0 if positive else value >= 0)):
            return f"--{name} must be a finite number {'> 0' if positive else '>= 0'}, got {value}"
    if args.data == "synthetic" and not 1 <= args.max_disparity < args.crop[1]:
        return (f"--max-disparity must be in 1..{args.crop[1] - 1}, below the crop width (--crop H W): a "
                f"disparity of the width or more has no match inside the crop; got {args.max_disparity}")
    try:
        device = torch.device(args.device)
    except RuntimeError:
        device = None
    if device is None or device.type not in ("cpu", "cuda"):
        return f"--device must be cpu or cuda[:N], got {args.device!r}"
    return memory_problem(args, device)


def memory_problem(args: argparse.Namespace, device: torch.device) -> str | None:
    """A dense batch that cannot fit, said before minutes of example generation end in an allocation
    failure: every crop row's scores against every column (``training.losses.dense_candidates``,
    B x H x W x W float32) and their gradient are a lower bound of a step's memory."""
    if args.mode != "dense" or args.batch_size is None or device.type != "cpu":
        return None
    height, width = args.crop
    # --both-views scores the mirrored pair as well: a second volume and its gradient.
    needed = (4 if args.both_views else 2) * args.batch_size * height * width * width * 4
    processes = max(1, int(os.environ.get("LOCAL_WORLD_SIZE", "1")))
    available = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES") // processes
    if needed <= available:
        return None
    gib = 1 << 30
    return (f"--batch-size {args.batch_size} of {height}x{width} crops needs at least {needed / gib:.0f} GiB "
            f"per process (the B x H x W x W matching scores and their gradient); this machine has "
            f"{available / gib:.0f} GiB per process: use a smaller --batch-size or --crop")


def _out_of_memory(error: RuntimeError) -> bool:
    """torch reports an allocation that failed as a RuntimeError (CUDA: its OutOfMemoryError subclass)."""
    text = str(error)
    return isinstance(error, torch.OutOfMemoryError) or "can't allocate memory" in text or \
        "out of memory" in text.lower()


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    defaults = MODE_DEFAULTS[args.mode]
    command = recorded_command(sys.argv[1:] if argv is None else argv, args)
    if problem := argument_problem(args):
        print(f"training.train: error: {problem}", file=sys.stderr)
        return 2
    if args.standardize_window and (args.standardize_window < 3 or args.standardize_window % 2 == 0):
        print(f"training.train: error: --standardize-window must be 0 or odd and >= 3, got "
              f"{args.standardize_window}", file=sys.stderr)
        return 2
    config = TrainConfig(config=args.config, channels=args.channels, shared=args.shared,
                         standardize_window=args.standardize_window,
                         adaptive_support=args.adaptive_support,
                         temperature=args.temperature, data=args.data,
                         mode=args.mode, iterations=args.iterations or defaults["iterations"],
                         batch_size=args.batch_size or defaults["batch_size"], lr=args.lr,
                         schedule=args.schedule, seed=args.seed, crop=tuple(args.crop),
                         max_disparity=args.max_disparity, augmentation=args.augmentation, label=args.label,
                         edge_weight=args.edge_weight, edge_region=args.edge_region,
                         sgm_loss=args.sgm_loss, both_views=args.both_views,
                         subpixel_loss=args.subpixel_loss,
                         rectification_error=args.rectification_error,
                         vignetting=args.vignetting, clean_views=args.clean_views,
                         curved_surfaces=args.curved_surfaces, fine_textures=args.fine_textures,
                         photo_textures=args.photo_textures,
                         downsampled_views=args.downsampled_views,
                         camera_draws=args.camera_draws, val_every=args.val_every, val_pairs=args.val_pairs,
                         cones=args.cones, out=args.out,
                         threads=args.threads, stop_after=args.stop_after, device=args.device,
                         time_budget_s=args.time_budget,
                         workers=args.workers,
                         init_from=args.init_from, command=command)
    try:
        summary = train(config, resume=resolve_resume(args.resume, args.out))
    except (OSError, ValueError) as error:
        print(f"training.train: error: {error}", file=sys.stderr)
        return 1
    except (MemoryError, RuntimeError) as error:
        if not isinstance(error, MemoryError) and not _out_of_memory(error):
            raise
        first = str(error).strip().splitlines()[0] if str(error).strip() else type(error).__name__
        print(f"training.train: error: out of memory ({first}); use a smaller --batch-size, --crop or "
              "--channels", file=sys.stderr)
        return 1
    if os.environ.get("RANK", "0") == "0":  # under torchrun only rank 0 reports
        print(json.dumps({k: v for k, v in summary.items() if k != "metrics"}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
