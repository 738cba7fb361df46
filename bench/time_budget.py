"""Time budget: does a candidate folder predict a KITTI-size pair within +10 % of the default's time?

    python -m bench time_budget --candidate NAME|DIR [--default NAME|DIR]
                                [--rounds 8] [--calls 4] [--threads 2] [--json F]

The default model must be the folder the rule ranks first *within the KITTI-size time budget* (issue 11,
``export.rank``): at most ``TIME_BUDGET`` times the current default's predict. A user runs one model per
process, and on a shared 2-core machine one process's towers can run 0.44 or 0.74 s with the same
settings (docs/performance.md, "Run-to-run variance"), so one process per model, as in the suite, can
put a 5 % difference anywhere between 0.99x and 1.15x. Here every round starts a fresh process for
each folder, alternating which goes first; each process warms up on a small pair (as ``adsm serve``
does), then times ``--calls`` warm calls of the suite's textured KITTI-size pair (375 x 1242, D = 192,
``bench.runtime.realistic_images``) and reports their median ``total``. The verdict reads the ratio of
the per-folder medians over the rounds; the per-round ratios (each round's two processes side by side)
give its spread.
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
from pathlib import Path

from bench import positive_int
from bench.suite import SIZES, checkout_commit, machine_description, model_folder

KITTI_SIZE, KITTI_DISPARITIES = SIZES["kitti"][:2], SIZES["kitti"][2]  # the suite's KITTI-size pair
# The budget of issue 11: a new default may cost at most 10 % more KITTI-size predict time.
TIME_BUDGET = 1.10


def warm_call_seconds(folder: str, *, calls: int, threads: int) -> float:
    """Median ``total`` seconds of ``calls`` warm KITTI-size calls of one folder, in this process."""
    import numpy as np

    from bench.runtime import realistic_images
    from service.matcher import Matcher, MatchOptions

    left, right = realistic_images(*KITTI_SIZE, KITTI_DISPARITIES, np.random.default_rng(0))
    matcher = Matcher.from_folder(folder, threads=threads)
    matcher.warmup()
    options = MatchOptions(max_disparity=KITTI_DISPARITIES)
    matcher(left, right, options)  # the first KITTI-size call grows the volumes and the arena
    return statistics.median(matcher(left, right, options).timings["total"] for _ in range(calls))


def verdict(default: list[float], candidate: list[float], *, budget: float = TIME_BUDGET) -> dict:
    """Ratio of the medians, the per-round ratios and whether the candidate fits ``budget``.

    >>> verdict([1.0, 1.1, 1.0], [1.05, 1.2, 1.08])["ratio"]
    1.08
    """
    if len(default) != len(candidate) or not default:
        raise ValueError("need one time per round for each folder, at least one round")
    ratio = statistics.median(candidate) / statistics.median(default)
    rounds = [c / d for c, d in zip(candidate, default, strict=True)]
    return {"ratio": round(ratio, 4), "round_ratios": [round(r, 4) for r in rounds],
            "round_median": round(statistics.median(rounds), 4), "budget": budget, "fits": ratio <= budget}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench time_budget", description=__doc__.split("\n")[0])
    parser.add_argument("--candidate", required=True, metavar="DIR", help="the folder that would replace")
    parser.add_argument("--default", metavar="DIR", help="the current default (service/models/DEFAULT's)")
    parser.add_argument("--rounds", type=positive_int, default=8, help="fresh processes per folder (8)")
    parser.add_argument("--calls", type=positive_int, default=4, help="timed warm calls per process (4)")
    parser.add_argument("--threads", type=positive_int, default=2)
    parser.add_argument("--json", type=Path, help="also write every figure to this JSON file")
    parser.add_argument("--child", metavar="DIR", help=argparse.SUPPRESS)  # one folder, in this process
    args = parser.parse_args(argv)
    if args.child:
        print(json.dumps(warm_call_seconds(args.child, calls=args.calls, threads=args.threads)))
        return 0
    from service.features.manifest import default_model_dir

    folders = {"default": str(model_folder(args.default) if args.default else default_model_dir()),
               "candidate": str(model_folder(args.candidate))}
    for folder in folders.values():
        if not (Path(folder) / "manifest.json").is_file():
            raise ValueError(f"{folder} is not a model folder (no manifest.json)")
    seconds: dict[str, list[float]] = {"default": [], "candidate": []}
    for round_ in range(args.rounds):
        order = ("default", "candidate") if round_ % 2 == 0 else ("candidate", "default")
        for role in order:
            child = [sys.executable, "-m", "bench", "time_budget", "--candidate", folders["candidate"],
                     f"--calls={args.calls}", f"--threads={args.threads}", f"--child={folders[role]}"]
            done = subprocess.run(child, capture_output=True, text=True, check=False)
            if done.returncode:
                raise RuntimeError(f"{folders[role]} failed: {done.stderr.strip().splitlines()[-1:]}")
            seconds[role].append(float(done.stdout.strip().splitlines()[-1]))
    result = verdict(seconds["default"], seconds["candidate"])
    machine, commit = machine_description(), checkout_commit()
    print(f"KITTI size {KITTI_SIZE[0]} x {KITTI_SIZE[1]}, D {KITTI_DISPARITIES}, {args.threads} threads, "
          f"{machine}, commit {commit}; median warm call of {args.calls} per process, {args.rounds} "
          "processes per folder, alternating")
    for role, folder in folders.items():
        values = seconds[role]
        print(f"  {role:<9} {folder:<40} median {statistics.median(values):.3f} s "
              f"(range {min(values):.3f}-{max(values):.3f})")
    spread = f"{min(result['round_ratios']):.3f}-{max(result['round_ratios']):.3f}"
    print(f"  ratio of the medians {result['ratio']:.3f}x (per round: median {result['round_median']:.3f}x, "
          f"range {spread}); budget {TIME_BUDGET:.2f}x: {'fits' if result['fits'] else 'outside'}")
    if args.json:
        args.json.write_text(json.dumps({"machine": machine, "commit": commit, "rounds": args.rounds,
                                         "calls": args.calls, "threads": args.threads, "folders": folders,
                                         "seconds": seconds, **result}, indent=2) + "\n",
                             encoding="utf-8")
    return 0
