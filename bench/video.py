"""Video input: how fast StereoVideo hands over frames, wanted or passed over, and its memory over a clip.

    python -m bench video [--size 1080x1920] [--frames 60]

Writes a synthetic stereo clip (a textured scene panning one pixel a frame, ``bench.runtime``'s
textures) as two H.264 files (libx264 ``veryfast``, crf 18: a camera's high-quality setting) and as
two Ut Video files (lossless, intra-only), then times ``StereoVideo.pairs`` over it: every frame wanted
(decoded and converted to RGB), no frame wanted (what frames of other ``--shard``s or
``--skip-existing`` ones cost: decoded but not converted for H.264, only demuxed for Ut Video), and the
resident memory while the wanted run goes. Needs the ``video`` extra. The figures go in docs/service.md,
"Video input": against about a second of matching per KITTI-size pair, passing over a frame is cheap.
"""

from __future__ import annotations

import argparse
import gc
import os
import tempfile
import time
from pathlib import Path

import numpy as np

from bench import positive_int
from bench.runtime import realistic_images
from service.io.video import StereoVideo


def _rss_mib() -> float:
    with open("/proc/self/statm", encoding="ascii") as stream:
        return int(stream.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 2**20


def _write(path: Path, scene: np.ndarray, width: int, frames: int, codec: str) -> None:
    """``frames`` views of ``width`` columns panning across ``scene``, encoded one at a time."""
    import av

    with av.open(str(path), "w") as container:
        stream = container.add_stream(codec, rate=30)
        stream.height, stream.width = scene.shape[0], width
        if codec == "libx264":
            stream.pix_fmt, stream.options = "yuv420p", {"preset": "veryfast", "crf": "18"}
        else:
            stream.pix_fmt = "gbrp"
        for index in range(frames):
            view = np.ascontiguousarray(scene[:, index:index + width])
            container.mux(stream.encode(av.VideoFrame.from_ndarray(view, format="rgb24")))
        container.mux(stream.encode())


def _run(left: Path, right: Path, wanted: bool) -> tuple[float, float, float, int]:
    """Pairs per second; resident memory (MiB) gained by the first 5 pairs, and gained after them (a
    reader that kept frames would grow with the clip); frames decoded."""
    video = StereoVideo.open(left, right)
    before = _rss_mib()
    settled = peak = before
    started = time.perf_counter()
    count = 0
    for count, _frame in enumerate(video.pairs(wanted=lambda index: wanted), start=1):
        if count == 5:
            settled = peak = _rss_mib()
        elif count % 5 == 0:
            peak = max(peak, _rss_mib())
    return count / (time.perf_counter() - started), settled - before, peak - settled, video.frames_decoded


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench video", description=__doc__.splitlines()[0])
    parser.add_argument("--size", default="1080x1920", help="HEIGHTxWIDTH of one view (default 1080x1920)")
    parser.add_argument("--frames", type=positive_int, default=60, help="frames in the clip (default 60)")
    args = parser.parse_args(argv)
    height, width = (int(part) for part in args.size.lower().split("x"))
    print(f"{args.frames} frames of {width}x{height} per view; load average {os.getloadavg()[0]:.1f} "
          f"on {os.cpu_count()} CPUs")
    codecs = {"libx264": "mp4", "utvideo": "avi"}
    with tempfile.TemporaryDirectory() as folder:
        files = {codec: [Path(folder) / f"{side}.{suffix}" for side in ("left", "right")]
                 for codec, suffix in codecs.items()}
        scenes = realistic_images(height, width + args.frames, 64, np.random.default_rng(0))
        for codec, paths in files.items():
            for path, scene in zip(paths, scenes, strict=True):
                _write(path, scene, width, args.frames, codec)
        del scenes  # freed before measuring, so resident memory counts the reading alone
        gc.collect()
        for codec, paths in files.items():
            megabytes = sum(path.stat().st_size for path in paths) / 2**20
            for wanted in (True, False):
                rate, first, then, decoded = _run(*paths, wanted)
                print(f"{codec:8} {megabytes:7.1f} MB  {'wanted' if wanted else 'passed over':11}  "
                      f"{rate:7.1f} pairs/s  {decoded:4d} frames decoded  RSS +{first:.1f} MiB by pair 5, "
                      f"+{then:.1f} MiB after")
    return 0
