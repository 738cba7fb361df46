"""Runs ``adsm predict``'s pairs through one loaded matcher: each pair checked by its headers, decoded,
rectified when the calibration asks for it, matched, written and diagnosed; a batch with a progress line
per pair and a summary on stderr, a failed pair reported and passed over."""

from __future__ import annotations

import argparse
import json
import sys
import time
from collections.abc import Iterator, Sequence
from typing import TYPE_CHECKING

import numpy as np

from service.cli.predict.checks import check_size, pair_size, right_path, search_options
from service.cli.predict.outputs import Targets, check_paths, write_maps, write_metric
from service.cli.predict.sources import Failed, Frames, Item, Pair, Skipped, frame_name
from service.datasets import StereoSample
from service.io import read_pair
from service.io.video import StereoVideo
from service.limits import RequestLimits

if TYPE_CHECKING:  # imported when a pair runs: `adsm --help` must not pay for Numba or OpenCV
    from service.calibration import StereoCalibration
    from service.calibration.rectify import Rectifier
    from service.matcher import Matcher, MatchOptions, StereoResult


class Runner:
    """Runs pairs through one loaded matcher and writes their files."""

    def __init__(self, args: argparse.Namespace, matcher: Matcher, options: MatchOptions, targets: Targets,
                 calibration: StereoCalibration | None, limits: RequestLimits, *, loaded: float) -> None:
        self.args, self.matcher, self.options, self.targets = args, matcher, options, targets
        self.calibration = calibration
        self.limits = limits
        self.rectifier: Rectifier | None = None
        self.load_seconds = loaded

    def one(self, pair: Pair | Frames) -> None:
        begun = time.perf_counter()
        if isinstance(pair, Frames):
            size = (pair.left.shape[0], pair.left.shape[1])
            begun -= pair.decode_seconds
        else:
            size = pair_size(pair)
            check_paths(self.targets, pair.name, [pair.left, right_path(pair)])
        options = search_options(self.options, pair.max_disparity, size[1])
        check_size(size, self.matcher.manifest, self.limits, options)
        if isinstance(pair, Frames):
            left, right = pair.left, pair.right
        else:
            left, right = read_pair(pair.left, right_path(pair), names=(f"left image {str(pair.left)!r}",
                                                                         f"right image {str(pair.right)!r}"))
        calibration = None if self.calibration is None else self.calibration.for_size(*size)
        if calibration is not None and calibration.needs_rectification:
            if self.rectifier is None:
                from service.calibration.rectify import Rectifier

                self.rectifier = Rectifier(calibration)
            left, right = self.rectifier(left, right)
        decoded = time.perf_counter()
        result = self.matcher(left, right, options)
        matched = time.perf_counter()
        write_maps(self.targets, pair.name, result)
        if calibration is not None and (self.targets.depth or self.targets.pointcloud):
            write_metric(self.targets, pair.name, calibration, result, left,
                         drop_filled=self.args.drop_filled, max_depth=self.args.max_depth)
        if not self.args.no_check:
            self._diagnose(pair.name, left, right, result)
        if self.args.timings:
            stages = {stage: seconds for stage, seconds in result.timings.items() if stage != "total"}
            timings = {"load_model": self.load_seconds, "decode": decoded - begun, **stages}
            timings["match"] = matched - decoded
            timings["encode"] = time.perf_counter() - matched
            timings["total"] = time.perf_counter() - begun + self.load_seconds
            self.load_seconds = 0.0  # paid once
            rounded = {stage: round(seconds, 6) for stage, seconds in timings.items()}
            print(json.dumps(rounded), file=sys.stderr)

    def file_items(self, pairs: list[Pair]) -> Iterator[Item]:
        for pair in pairs:
            yield Skipped(pair.name) if self._written(pair.name) else pair

    def video_items(self, video: StereoVideo, shard: tuple[int, int] | None) -> Iterator[Item]:
        """The shard's frames of ``video`` as pairs, decoded as they are reached; frames of other shards
        and --skip-existing ones are passed over (StereoVideo.pairs: not converted, not decoded where the
        codec allows)."""
        first, step = shard or (0, 1)

        def wanted(index: int) -> bool:
            return index % step == first and not self._written(frame_name(index))

        frames, index = video.pairs(wanted), -1
        while True:
            begun = time.perf_counter()
            try:
                frame = next(frames)
            except StopIteration:
                return
            except ValueError as error:  # the stream cannot go on: the failure ends the video
                yield Failed(frame_name(index + 1), str(error))
                return
            index = frame.index
            if index % step != first:
                continue
            name = frame_name(index)
            if frame.error is not None:
                yield Failed(name, frame.error)
            elif frame.views is None:
                yield Skipped(name)
            else:
                yield Frames(name, *frame.views, time.perf_counter() - begun)

    def sample_items(self, dataset: Sequence[StereoSample], indices: range) -> Iterator[Item]:
        """The pairs ``indices`` of ``dataset``, each drawn when it is reached; a pair's name is known once
        it is drawn, so --skip-existing skips it after that (generating is what there is to save)."""
        seen: set[str] = set()
        for index in indices:
            begun = time.perf_counter()
            try:
                sample = dataset[index]
            except (OSError, ValueError) as error:
                yield Failed(f"pair {index}", str(error))
                continue
            if sample.name in seen:  # its outputs would overwrite the other pair's
                yield Failed(sample.name, "another pair of the dataset has this name")
            elif self._written(sample.name):
                yield Skipped(sample.name)
            else:
                yield Frames(sample.name, sample.left, sample.right, time.perf_counter() - begun,
                             sample.max_disparity)
            seen.add(sample.name)

    def many(self, items: Iterator[Item], total: int | None, started: float) -> int:
        failed: list[str] = []
        skipped = done = 0
        for index, pair in enumerate(items, start=1):
            if isinstance(pair, Skipped):
                skipped += 1
                continue
            begun = time.perf_counter()
            try:
                if isinstance(pair, Failed):
                    raise ValueError(pair.reason)
                if isinstance(pair, Pair) and pair.right is None:
                    raise ValueError(f"no right image named like {pair.left.name}")
                if isinstance(pair, Frames):
                    begun -= pair.decode_seconds
                self.one(pair)
            except (OSError, ValueError) as error:
                failed.append(pair.name)
                print(f"adsm: error: {pair.name}: {error}", file=sys.stderr)
                continue
            done += 1
            rate = done / max(time.perf_counter() - started, 1e-9)
            print(f"[{index}/{'?' if total is None else total}] {pair.name} "
                  f"{time.perf_counter() - begun:.2f} s ({rate:.2f} pairs/s)", file=sys.stderr)
        elapsed = time.perf_counter() - started
        summary = f"adsm: {done} pairs written, {skipped} skipped, {len(failed)} failed in {elapsed:.1f} s"
        if done:
            summary += f" ({done / elapsed:.2f} pairs/s)"
        if failed:
            summary += ": " + ", ".join(failed[:10]) + (" ..." if len(failed) > 10 else "")
        print(summary, file=sys.stderr)
        return 1 if failed else 0

    def _written(self, name: str) -> bool:
        """--skip-existing and the pair's disparity file is there."""
        return bool(self.args.skip_existing) and self.targets.path(self.targets.disparity, name).exists()

    def _diagnose(self, name: str, left: np.ndarray, right: np.ndarray, result: StereoResult) -> None:
        from service.calibration.pair_check import check_pair
        from service.validation.codes import Validity

        valid_share = float((result.validity == Validity.VALID).mean()) if self.options.lr_check else None
        check = check_pair(left, right, max_disparity=self.args.max_disparity or left.shape[1] // 4)
        for warning in check.warnings(valid_share=valid_share):
            print(f"adsm: warning: {name}: {warning}", file=sys.stderr)
