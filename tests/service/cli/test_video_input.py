"""`adsm predict --data LEFT,RIGHT` / `--data sbs:VIDEO`: stereo videos decoded frame by frame (issue 12,
item 5). Videos are written here with PyAV from synthetic pairs of known disparity."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

from service.cli import main
from service.io.video import MISSING_EXTRA, StereoVideo
from tests.helpers import ROOT, require_module

SHIPPED = ROOT / "service" / "models" / "ncc-baseline"
HEIGHT, WIDTH = 40, 80
SHIFTS = (3, 5, 7, 4)  # frame i's disparity: a frame paired with the wrong one would show another


@pytest.fixture(scope="module")
def av():
    return require_module("av")


def stereo_frames(count: int, seed: int = 5) -> list[tuple[np.ndarray, np.ndarray]]:
    """Textured pairs: frame i's right view is its left shifted by SHIFTS[i] pixels."""
    rng = np.random.default_rng(seed)
    pairs = []
    for index in range(count):
        blocks = rng.integers(0, 256, (HEIGHT // 2, WIDTH // 2 + 8, 3), dtype=np.uint8)
        wide = np.repeat(np.repeat(blocks, 2, axis=0), 2, axis=1)  # 2x2 blocks: NCC-friendly texture
        shift = SHIFTS[index]
        # left(x) = wide(x), right(x) = wide(x + shift): the left pixel x is seen at x - shift on the right.
        left, right = wide[:, :WIDTH], wide[:, shift:shift + WIDTH]
        pairs.append((np.ascontiguousarray(left), np.ascontiguousarray(right)))
    return pairs


def write_video(av, path: Path, frames: list[np.ndarray], *, codec: str = "libx264") -> Path:
    """H.264 at qp 0 in 4:4:4 (near lossless, as a camera's high-quality setting), or an intra-only
    lossless codec (utvideo: every frame decodes alone)."""
    with av.open(str(path), "w") as container:
        stream = container.add_stream(codec, rate=10)
        stream.height, stream.width = frames[0].shape[:2]
        stream.pix_fmt = "yuv444p" if codec == "libx264" else "gbrp"
        if codec == "libx264":
            stream.options = {"qp": "0"}
        for frame in frames:
            container.mux(stream.encode(av.VideoFrame.from_ndarray(frame, format="rgb24")))
        container.mux(stream.encode())
    return path


def run(capsys, *argv: str) -> tuple[int, str, str]:
    code = main(["predict", *argv, "--max-disparity", "16", "--model", str(SHIPPED), "--format", "npy"])
    captured = capsys.readouterr()
    return code, captured.out, captured.err


def assert_disparity(path: Path, shift: int) -> None:
    disparity = np.load(path)
    assert disparity.shape == (HEIGHT, WIDTH)
    assert np.nanmedian(np.abs(disparity[8:-8, 16:-8] - shift)) < 0.25, (path.name, shift)


def test_two_videos_give_one_disparity_map_per_frame(capsys, tmp_path, av):
    pairs = stereo_frames(3)
    left = write_video(av, tmp_path / "left.mp4", [pair[0] for pair in pairs])
    right = write_video(av, tmp_path / "right.mp4", [pair[1] for pair in pairs])
    code, stdout, err = run(capsys, "--data", f"{left},{right}", "--out-dir", str(tmp_path / "out"))
    assert (code, stdout) == (0, ""), err
    names = sorted(path.name for path in (tmp_path / "out").iterdir())
    assert names == ["frame_000000.npy", "frame_000001.npy", "frame_000002.npy"]
    for index, name in enumerate(names):
        assert_disparity(tmp_path / "out" / name, SHIFTS[index])
    lines = err.strip().splitlines()
    assert lines[0].startswith("[1/3] frame_000000 ") and "pairs/s" in lines[0]
    assert lines[-1].startswith("adsm: 3 pairs written, 0 skipped, 0 failed")


def test_side_by_side_video_shards_and_skip_existing(capsys, tmp_path, av):
    pairs = stereo_frames(4)
    video = write_video(av, tmp_path / "sbs.mp4", [np.concatenate(pair, axis=1) for pair in pairs])
    out = tmp_path / "out"
    written = []
    for shard in ("0/2", "1/2"):
        code, _, err = run(capsys, "--data", f"sbs:{video}", "--out-dir", str(out), "--shard", shard)
        assert code == 0, err
        written.append([line.split()[1] for line in err.splitlines() if line.startswith("[")])
    assert written == [["frame_000000", "frame_000002"], ["frame_000001", "frame_000003"]]
    assert "[2/2] frame_000003" in err
    for index in range(4):
        assert_disparity(out / f"frame_{index:06d}.npy", SHIFTS[index])
    (out / "frame_000002.npy").unlink()
    code, _, err = run(capsys, "--data", f"sbs:{video}", "--out-dir", str(out), "--skip-existing")
    assert code == 0 and "[3/4] frame_000002" in err
    assert err.strip().splitlines()[-1].startswith("adsm: 1 pairs written, 3 skipped, 0 failed")


def test_a_shard_passes_over_other_frames_undecoded_where_the_codec_allows(tmp_path, av):
    pairs = stereo_frames(4)
    for codec, name, decoded in (("utvideo", "v.avi", 2 * 2), ("libx264", "v.mp4", 2 * 4)):
        left = write_video(av, tmp_path / f"left-{name}", [pair[0] for pair in pairs], codec=codec)
        right = write_video(av, tmp_path / f"right-{name}", [pair[1] for pair in pairs], codec=codec)
        video = StereoVideo.open(left, right)
        frames = list(video.pairs(wanted=lambda index: index % 2 == 1))
        assert [frame.index for frame in frames] == [0, 1, 2, 3]
        assert [frame.views is None for frame in frames] == [True, False, True, False]
        for frame in frames[1::2]:
            assert frame.views is not None and frame.error is None
            for view, truth in zip(frame.views, pairs[frame.index], strict=True):
                assert np.abs(view.astype(int) - truth).max() <= (0 if codec == "utvideo" else 3)
        # intra-only: the frames of other shards are only demuxed; H.264 predicts frames from earlier ones
        assert video.frames_decoded == decoded, codec


def test_different_frame_counts_warn_and_use_the_common_length(capsys, tmp_path, av):
    pairs = stereo_frames(3)
    left = write_video(av, tmp_path / "left.mp4", [pair[0] for pair in pairs])
    right = write_video(av, tmp_path / "right.mp4", [pair[1] for pair in pairs[:2]])
    code, _, err = run(capsys, "--data", f"{left},{right}", "--out-dir", str(tmp_path / "out"))
    assert code == 0, err
    warnings = [line for line in err.splitlines() if line.startswith("adsm: warning:")]
    assert len(warnings) == 1 and "3 frames" in warnings[0] and "first 2 pairs" in warnings[0], err
    assert sorted(path.name for path in (tmp_path / "out").iterdir()) == ["frame_000000.npy",
                                                                        "frame_000001.npy"]
    assert "[2/2] frame_000001" in err and "2 pairs written" in err


def test_a_length_the_headers_do_not_tell_is_warned_about_at_the_end(tmp_path, av):
    # Matroska keeps no frame count: the shorter video is found when it ends.
    pairs = stereo_frames(3)
    left = write_video(av, tmp_path / "left.mkv", [pair[0] for pair in pairs[:2]])
    right = write_video(av, tmp_path / "right.mkv", [pair[1] for pair in pairs])
    warnings: list[str] = []
    video = StereoVideo.open(left, right, warn=warnings.append)
    assert video.frame_count is None and warnings == []
    assert [frame.index for frame in video.pairs()] == [0, 1]
    assert warnings == [f"left video {str(left)!r} ends after 2 frames, before right video {str(right)!r} "
                        "does: only the first 2 pairs are used"]


def test_bad_videos_are_one_line_errors(capsys, tmp_path, av):
    pairs = stereo_frames(2)
    left = write_video(av, tmp_path / "left.mp4", [pair[0] for pair in pairs])
    small = write_video(av, tmp_path / "small.mp4", [pair[1][:, :40] for pair in pairs])
    odd = write_video(av, tmp_path / "odd.avi", [pair[0][:, :79] for pair in pairs], codec="utvideo")
    (tmp_path / "junk.mp4").write_bytes(b"not a video")
    cases = {
        f"{left},{small}": "has 80x40 frames and right video",
        f"{left},{tmp_path / 'junk.mp4'}": "junk.mp4' is not a readable video",
        f"{left},{tmp_path / 'missing.mp4'}": "missing.mp4' does not exist",
        f"sbs:{odd}": "79 pixels wide cannot be split",
        str(left): "is one file: give two videos as LEFT,RIGHT, or sbs:VIDEO",
    }
    for spec, fragment in cases.items():
        code, _, err = run(capsys, "--data", spec, "--out-dir", str(tmp_path / "out"))
        lines = err.strip().splitlines()
        assert code == 1 and len(lines) == 1 and lines[0].startswith("adsm: error: "), err
        assert fragment in lines[0], (fragment, lines[0])
    assert not (tmp_path / "out").exists()


def test_a_frame_that_cannot_be_decoded_fails_alone(capsys, tmp_path, av):
    pairs = stereo_frames(3)
    left = write_video(av, tmp_path / "left.avi", [pair[0] for pair in pairs], codec="utvideo")
    right = write_video(av, tmp_path / "right.avi", [pair[1] for pair in pairs], codec="utvideo")
    with av.open(str(left)) as container:
        packets = [(packet.pos, packet.size) for packet in container.demux(video=0) if packet.size]
    body = bytearray(left.read_bytes())
    start, size = packets[1]
    body[start + 4:start + size] = b"\xff" * (size - 4)  # frame 1's planes: garbage
    left.write_bytes(bytes(body))
    code, _, err = run(capsys, "--data", f"{left},{right}", "--out-dir", str(tmp_path / "out"), "--no-check")
    assert code == 1
    assert "adsm: error: frame_000001: left video" in err and "cannot decode frame 1" in err
    assert sorted(path.name for path in (tmp_path / "out").iterdir()) == ["frame_000000.npy",
                                                                        "frame_000002.npy"]
    summary = err.strip().splitlines()[-1]
    assert summary.startswith("adsm: 2 pairs written, 0 skipped, 1 failed")
    assert summary.endswith(": frame_000001")


def test_without_the_video_extra_one_line_names_it(capsys, tmp_path, monkeypatch):
    (tmp_path / "left.mp4").write_bytes(b"")
    (tmp_path / "right.mp4").write_bytes(b"")
    monkeypatch.setitem(sys.modules, "av", None)  # what `import av` meets when PyAV is not installed
    code, _, err = run(capsys, "--data", f"{tmp_path / 'left.mp4'},{tmp_path / 'right.mp4'}",
                       "--out-dir", str(tmp_path / "out"))
    assert (code, err) == (1, f"adsm: error: {MISSING_EXTRA}\n")
    assert "video extra" in MISSING_EXTRA and "pip install 'adsm-stereo[video]'" in MISSING_EXTRA
