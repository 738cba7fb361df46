"""Stereo video input: two videos whose frame i is pair i, or one side-by-side video, decoded lazily.

Decoded by PyAV (the ``video`` extra: FFmpeg's libraries inside its wheel; why this decoder:
docs/service.md, "Video input"). Frames are decoded one at a time, so a long video never sits in memory.
A frame the caller does not want is not converted to RGB, and with an intra-only codec (MJPEG, Ut Video,
HuffYUV, raw...) it is not even decoded; other codecs predict frames from earlier ones, so every frame
up to the last wanted one is decoded (a few milliseconds each, against a second or so to match a pair).

    video = StereoVideo.open("left.mp4", "right.mp4")      # or StereoVideo.open("sbs.mp4") (side by side)
    for frame in video.pairs(wanted=lambda index: index % 2 == 0):
        if frame.views is not None:
            left, right = frame.views                       # uint8 (H, W, 3) RGB each
"""

from __future__ import annotations

import dataclasses
import functools
import itertools
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import numpy as np

# Printed after "adsm: error: " when PyAV is not installed.
MISSING_EXTRA = "video input needs the video extra (pip install 'adsm-stereo[video]')"

Views = tuple[np.ndarray, np.ndarray]


def _av() -> Any:
    try:
        import av
    except ImportError:
        raise ValueError(MISSING_EXTRA) from None
    return av


@dataclasses.dataclass(frozen=True, eq=False)
class StereoFrame:
    """Frame ``index`` of a stereo video: its views (uint8 RGB (H, W, 3) left and right) when they were
    wanted and decoded; ``error`` says why a wanted frame has none."""

    index: int
    views: Views | None = None
    error: str | None = None


class _Stream:
    """One video file's first video stream, read frame by frame."""

    def __init__(self, path: Path, role: str) -> None:
        av = _av()
        self.path, self.role = path, role
        self.label = f"{role} {str(path)!r}"
        if not path.is_file():
            raise ValueError(f"{self.label} does not exist or is not a file")
        try:
            self.container = av.open(str(path))
        except av.FFmpegError as error:
            raise ValueError(f"{self.label} is not a readable video: {_reason(error)}") from None
        if not self.container.streams.video:
            self.container.close()
            raise ValueError(f"{self.label} holds no video stream")
        self.stream = self.container.streams.video[0]
        context = self.stream.codec_context
        self.size = (int(context.height), int(context.width))
        if min(self.size) < 1:
            self.container.close()
            raise ValueError(f"{self.label}: the frame size is not in the file's header")
        self.frame_count = int(self.stream.frames) or None  # 0: the container does not tell
        # One packet is one whole frame: a frame nobody wants need not be decoded.
        self.passes_undecoded = bool(context.codec.intra_only and not context.codec.delay)
        # FFmpeg's default slice threads, not frame threads: those hold a frame per core in flight (on a
        # many-core node, hundreds of MiB) to speed up what takes milliseconds against a second of matching.
        self.decoded = 0

    def frames(self) -> Iterator[Callable[[], np.ndarray]]:
        """One callable per frame, in order, giving that frame as uint8 RGB; call it before advancing."""
        av = _av()
        index = 0
        try:
            if self.passes_undecoded:
                for packet in self.container.demux(self.stream):
                    if packet.size:  # the last packet of a demux is an empty one
                        yield functools.partial(self._decode_packet, packet, index)
                        index += 1
            else:
                for frame in self.container.decode(self.stream):
                    self.decoded += 1
                    yield functools.partial(_rgb, frame)
                    index += 1
        except av.FFmpegError as error:
            raise ValueError(f"{self.label}: cannot decode frame {index}: {_reason(error)}") from None

    def _decode_packet(self, packet: Any, index: int) -> np.ndarray:
        try:
            frames = packet.decode()
        except _av().FFmpegError as error:
            raise ValueError(f"{self.label}: cannot decode frame {index}: {_reason(error)}") from None
        if len(frames) != 1:
            raise ValueError(f"{self.label}: frame {index}: one packet gave {len(frames)} frames")
        self.decoded += 1
        return _rgb(frames[0])

    def close(self) -> None:
        self.container.close()


class StereoVideo:
    """The pairs of a stereo video: ``left`` and ``right`` files, or one side-by-side file (left view in
    the left half of each frame). ``size`` is one view's (height, width); ``frame_count`` the number of
    pairs the headers promise (None when a container does not tell)."""

    def __init__(self, streams: list[_Stream], *, warn: Callable[[str], None]) -> None:
        self.streams, self.warn = streams, warn
        if len(streams) == 2:
            left, right = streams
            if left.size != right.size:
                self.close()
                raise ValueError(f"{left.label} has {_wxh(left.size)} frames and {right.label} "
                                 f"{_wxh(right.size)}: the two views of a pair must be the same size")
            self.size = left.size
        else:
            height, width = streams[0].size
            if width % 2:
                self.close()
                raise ValueError(f"{streams[0].label}: frames {width} pixels wide cannot be "
                                 "split into two equal halves")
            self.size = (height, width // 2)
        counts = [stream.frame_count for stream in streams]
        known = [count for count in counts if count is not None]
        self.frame_count = min(known) if len(known) == len(counts) else None
        self._warned = False
        if len(known) == 2 and known[0] != known[1]:  # told now, not after hours of matching
            self._warn(f"{streams[0].label} has {known[0]} frames and {streams[1].label} {known[1]}: "
                       f"only the first {min(known)} pairs are used")

    @classmethod
    def open(cls, left: str | Path, right: str | Path | None = None, *,
             warn: Callable[[str], None] = lambda message: None) -> StereoVideo:
        """Two videos (frame i of each is pair i), or with ``right`` None one side-by-side video.
        ValueError with one line for a missing extra, file or stream, or views of different sizes."""
        if right is None:
            return cls([_Stream(Path(left), "side-by-side video")], warn=warn)
        first = _Stream(Path(left), "left video")
        try:
            second = _Stream(Path(right), "right video")
        except ValueError:
            first.close()
            raise
        return cls([first, second], warn=warn)

    @property
    def frames_decoded(self) -> int:
        """Frames decoded so far, all files together (a frame passed over undecoded does not count)."""
        return sum(stream.decoded for stream in self.streams)

    def pairs(self, wanted: Callable[[int], bool] = lambda index: True) -> Iterator[StereoFrame]:
        """One StereoFrame per frame index, in order, until the shorter video ends (a warning names both
        lengths when they differ); views only for the indices ``wanted`` accepts. A frame that cannot be
        decoded alone comes with its error and the video goes on; a stream that cannot go on (a broken
        predicted frame) raises ValueError naming the file and the frame. Once: the files close after."""
        try:
            streams = [stream.frames() for stream in self.streams]
            for index in itertools.count():
                ahead = [next(stream, None) for stream in streams]
                frames = [frame for frame in ahead if frame is not None]
                if len(frames) < len(ahead):
                    if frames:  # one video ended, the other did not
                        shorter, longer = self.streams if ahead[0] is None else self.streams[::-1]
                        self._warn(f"{shorter.label} ends after {index} frames, before {longer.label} "
                                   f"does: only the first {index} pairs are used")
                    return
                if not wanted(index):
                    yield StereoFrame(index)
                    continue
                try:
                    views = self._views([frame() for frame in frames], index)
                except ValueError as error:
                    yield StereoFrame(index, error=str(error))
                    continue
                yield StereoFrame(index, views)
        finally:
            self.close()

    def _views(self, pixels: list[np.ndarray], index: int) -> Views:
        for stream, frame in zip(self.streams, pixels, strict=True):
            if frame.shape[:2] != stream.size:
                raise ValueError(f"{stream.label}: frame {index} is {_wxh(frame.shape[:2])}, the video's "
                                 f"frames {_wxh(stream.size)}")
        if len(pixels) == 2:
            return pixels[0], pixels[1]
        width = self.size[1]
        return np.ascontiguousarray(pixels[0][:, :width]), np.ascontiguousarray(pixels[0][:, width:])

    def _warn(self, message: str) -> None:
        if not self._warned:  # once: the headers' count and the actual end tell the same story
            self._warned = True
            self.warn(message)

    def close(self) -> None:
        for stream in self.streams:
            stream.close()


def _rgb(frame: Any) -> np.ndarray:
    return np.asarray(frame.to_ndarray(format="rgb24"))


def _wxh(size: tuple[int, ...]) -> str:
    return f"{size[1]}x{size[0]}"


def _reason(error: BaseException) -> str:
    """FFmpeg's words without PyAV's errno prefix and file name repeat."""
    return getattr(error, "strerror", None) or str(error)
