"""Input and limits (issue 12, item 8): the CLI refuses what the server refuses, from the image headers and
before anything is allocated; grey arrays and keyword options in the Python API; ``adsm --version``."""

from __future__ import annotations

import subprocess
import sys
import zlib
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from service.cli import main
from service.limits import DisparityRangeError, LimitError, RequestLimits, check_request
from service.matcher import Matcher, MatchOptions
from tests.helpers import ROOT

SHIPPED = ROOT / "service" / "models" / "ncc-baseline"


@pytest.fixture(scope="module")
def default_matcher() -> Matcher:
    return Matcher.from_folder(threads=2)


def png_header_only(path: Path, width: int, height: int) -> Path:
    """A PNG whose header announces ``width x height`` grey pixels and whose pixel data is one empty
    row: anything that decodes it fails, so a refusal naming a limit proves nothing was decoded."""
    def chunk(kind: bytes, body: bytes) -> bytes:
        return len(body).to_bytes(4, "big") + kind + body + zlib.crc32(kind + body).to_bytes(4, "big")

    ihdr = width.to_bytes(4, "big") + height.to_bytes(4, "big") + bytes([8, 0, 0, 0, 0])
    path.write_bytes(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", zlib.compress(b"\0"))
                     + chunk(b"IEND", b""))
    return path


def adsm(*argv: str, env: dict[str, str] | None = None) -> subprocess.CompletedProcess:
    import os

    environment = {**os.environ, **(env or {})}
    return subprocess.run([sys.executable, "-m", "service", *argv], capture_output=True, text=True,
                          timeout=120, check=False, env=environment)


def test_a_12000_pixel_square_pair_exits_with_one_line_not_an_oom_kill(tmp_path) -> None:
    left = png_header_only(tmp_path / "l.png", 12000, 12000)
    right = png_header_only(tmp_path / "r.png", 12000, 12000)
    done = adsm("predict", str(left), str(right), "-o", str(tmp_path / "d.png"))
    assert done.returncode == 1 and "Traceback" not in done.stderr
    assert done.stderr.strip() == ("adsm: error: 12000 x 12000 = 144000000 pixels exceeds adsm predict's "
                                   "limit of 2100000 (--max-pixels or ADSM_MAX_PIXELS); send smaller images")
    # Raised by the variable, the cost volume is next; raised again by the flag, the memory plan.
    done = adsm("predict", str(left), str(right), "-o", str(tmp_path / "d.png"),
                env={"ADSM_MAX_PIXELS": "200_000_000"})
    assert done.returncode == 1
    assert "cost-volume cells exceeds adsm predict's limit of 100000000" in done.stderr
    done = adsm("predict", str(left), str(right), "-o", str(tmp_path / "d.png"), "--max-pixels", "200000000",
                "--max-cost-cells", "100000000000")
    assert done.returncode == 1 and "per request (--max-memory-mib or ADSM_MAX_REQUEST_BYTES)" in done.stderr
    assert len(done.stderr.strip().splitlines()) == 1 and not (tmp_path / "d.png").exists()


def test_the_disparity_range_rule_is_the_servers(capsys, tmp_path) -> None:
    image = np.random.default_rng(0).integers(0, 256, (40, 84, 3), dtype=np.uint8)
    Image.fromarray(image).save(tmp_path / "l.png")
    Image.fromarray(image).save(tmp_path / "r.png")
    common = [str(tmp_path / "l.png"), str(tmp_path / "r.png"), "-o", str(tmp_path / "d.png"), "--model",
              str(SHIPPED)]
    assert main(["predict", *common, "--max-disparity", "100000"]) == 1
    assert capsys.readouterr().err == ("adsm: error: max_disparity 100000 exceeds adsm predict's limit of "
                                       "256 (--disparity-limit or ADSM_MAX_DISPARITY)\n")
    assert main(["predict", *common, "--max-disparity", "100"]) == 1
    assert capsys.readouterr().err == ("adsm: error: max_disparity 100 exceeds the image width 84: at most "
                                       "84 disparities (0..83) fit\n")
    assert main(["predict", *common, "--max-disparity", "84", "--no-check"]) == 0


@pytest.mark.parametrize(
    ("height", "width", "max_disparity", "settings"),
    [
        (40, 84, None, {}), (40, 84, 84, {}), (40, 84, 85, {}), (40, 84, 257, {}), (40, 84, 300, {}),
        (1, 1, 16, {}), (1, 1, None, {}), (1500, 1400, None, {}), (1000, 1000, 200, {}),
        (1000, 1000, 128, {"max_cost_cells": 100_000_000}),
        (1000, 1000, 101, {"max_cost_cells": 100_000_000}),
        (600, 800, 128, {"max_request_bytes": 300 * 2**20}), (2, 100_000, 64, {"max_pixels": 300_000}),
    ],
)
def test_cli_and_server_refuse_the_same_requests(default_matcher, height, width, max_disparity,
                                                 settings) -> None:
    """Pins service.limits.check_request (the CLI's) to the server's own check until the routes call it:
    the same requests pass, and refusals map to the same status (range 400, size 413)."""
    from service.api.errors import status_of
    from service.api.inference import InferenceService
    from service.api.settings import Settings

    manifest = default_matcher.manifest
    server = InferenceService(Settings(**settings, warmup=False), matcher=default_matcher)
    options = MatchOptions(max_disparity=max_disparity)
    try:
        server._check_request(height, width, options)
        status = 200
    except ValueError as error:  # a domain error; the status the server answers it with
        status = status_of(error)
    try:
        check_request(height, width, manifest, RequestLimits(**settings), max_disparity=max_disparity)
        ours = 200
    except DisparityRangeError:
        ours = 400
    except LimitError:
        ours = 413
    if width * height > RequestLimits(**settings).max_pixels:
        status = 413  # the server refuses these earlier, on the image header (service.io.image_size)
    assert ours == status


def test_the_servers_defaults_are_the_shared_ones() -> None:
    from service.api.settings import Settings

    server, shared = Settings(), RequestLimits()
    for field in ("max_pixels", "max_disparity", "max_cost_cells", "max_request_bytes"):
        assert getattr(server, field) == getattr(shared, field), field


def test_limits_from_the_environment_and_flags() -> None:
    limits = RequestLimits.from_env({"ADSM_MAX_PIXELS": "1_000", "ADSM_MAX_DISPARITY": " "}, max_cost_cells=7)
    assert (limits.max_pixels, limits.max_disparity, limits.max_cost_cells) == (1000, 256, 7)
    assert RequestLimits.from_env({"ADSM_MAX_PIXELS": "1000"}, max_pixels=5).max_pixels == 5
    with pytest.raises(ValueError, match="ADSM_MAX_COST_CELLS must be an integer"):
        RequestLimits.from_env({"ADSM_MAX_COST_CELLS": "lots"})
    with pytest.raises(ValueError, match="max_pixels must be an integer >= 1"):
        RequestLimits(max_pixels=0)


def test_grey_arrays_and_keyword_options() -> None:
    matcher = Matcher.from_folder(SHIPPED, threads=2)
    rng = np.random.default_rng(5)
    wide = np.repeat(rng.integers(0, 256, (30, 44), dtype=np.uint8), 2, axis=1)
    left, right = np.ascontiguousarray(wide[:, :-4]), np.ascontiguousarray(wide[:, 4:])
    colour = matcher(np.dstack([left] * 3), np.dstack([right] * 3), MatchOptions(max_disparity=16))
    grey = matcher(left, right, max_disparity=16)
    np.testing.assert_array_equal(grey.disparity, colour.disparity)
    single_channel = matcher(left[..., None], right, max_disparity=16)
    np.testing.assert_array_equal(single_channel.disparity, colour.disparity)
    # keywords replace the fields of an options object
    replaced = matcher(left, right, MatchOptions(max_disparity=16, subpixel=False), subpixel=True)
    np.testing.assert_array_equal(replaced.disparity, colour.disparity)
    with pytest.raises(ValueError, match="unknown match option 'max_disp'; MatchOptions has max_disparity"):
        matcher(left, right, max_disp=16)


def test_version(capsys) -> None:
    from service import __version__

    with pytest.raises(SystemExit) as leaving:
        main(["--version"])
    assert leaving.value.code == 0
    assert capsys.readouterr().out.startswith(f"adsm {__version__} (default model ")
