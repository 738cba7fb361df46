"""Bad-input catalog: every malformed or hostile request gets its documented status and a clear JSON detail,
the server stays up, and the next valid request succeeds (no leaked queue place, no stuck state).

Inputs the service is documented to accept although they are unusual (grey + colour, 16-bit, palette,
alpha, CMYK, EXIF orientation, 1x1, a foreign Accept header) are in the catalog too, answered 200.
Against the real default model on 64x96 pairs, in process (httpx's ASGI transport).
"""

from __future__ import annotations

import dataclasses
import io
import zlib
from collections.abc import AsyncIterator, Callable
from typing import Any

import httpx
import numpy as np
import pytest
from PIL import Image

from service.api import Settings, create_app
from tests.helpers import ready_client

HEIGHT, WIDTH, SHIFT = 64, 96, 4
SETTINGS = Settings(
    queue_size=0,  # one admission at a time: a leaked place would turn the next valid request into a 503
    max_body_bytes=200_000, max_pixels=HEIGHT * WIDTH, max_disparity=256, max_cost_cells=HEIGHT * WIDTH * 128,
)
VALID_QUERY = {"max_disparity": 16}

pytestmark = pytest.mark.anyio


def _texture() -> tuple[np.ndarray, np.ndarray]:
    """Smoothed random texture seen with disparity SHIFT (left[y, x] == right[y, x - SHIFT])."""
    noise = np.random.default_rng(11).integers(0, 256, (HEIGHT, WIDTH + SHIFT, 3)).astype(np.float32)
    texture = ((noise + np.roll(noise, 1, axis=0) + np.roll(noise, 1, axis=1)) / 3).astype(np.uint8)
    return np.ascontiguousarray(texture[:, :WIDTH]), np.ascontiguousarray(texture[:, SHIFT:])


LEFT, RIGHT = _texture()


def encode(image: np.ndarray | Image.Image, format: str = "PNG", **options: Any) -> bytes:
    buffer = io.BytesIO()
    image = image if isinstance(image, Image.Image) else Image.fromarray(image)
    image.save(buffer, format=format, **options)
    return buffer.getvalue()


def files(left: bytes, right: bytes, **extra: Any) -> dict[str, Any]:
    return {"left": ("left.png", left, "image/png"), "right": ("right.png", right, "image/png"), **extra}


PAIR = files(encode(LEFT), encode(RIGHT))


def png_claiming(width: int, height: int) -> bytes:
    """A 1x1 PNG whose header announces ``width`` x ``height`` (decoding would fail: 413 proves the header
    alone was judged)."""
    data = bytearray(encode(np.zeros((1, 1), np.uint8)))
    data[16:24] = width.to_bytes(4, "big") + height.to_bytes(4, "big")
    data[29:33] = zlib.crc32(bytes(data[12:29])).to_bytes(4, "big")  # IHDR checksum
    return bytes(data)


def zlib_bomb() -> bytes:
    """A real, valid 4000 x 4000 grey PNG (16 MB of pixels) in about 16 KB."""
    return encode(Image.new("L", (4000, 4000)), optimize=True)


def ico_holding(image: bytes) -> bytes:
    """An ICO whose one entry is ``image`` (a PNG): Pillow's ICO reader would decode it inside open()."""
    entry = bytes([0, 0, 0, 0]) + (1).to_bytes(2, "little") + (32).to_bytes(2, "little")
    entry += len(image).to_bytes(4, "little") + (22).to_bytes(4, "little")
    return b"\0\0\1\0\1\0" + entry + image


def icns_holding(image: bytes) -> bytes:
    """An ICNS whose one 'ic10' element is ``image`` (a PNG)."""
    element = b"ic10" + (8 + len(image)).to_bytes(4, "big") + image
    return b"icns" + (8 + len(element)).to_bytes(4, "big") + element


def multipart_body(boundary: str = "x") -> bytes:
    parts = b"".join(
        f'--{boundary}\r\nContent-Disposition: form-data; name="{name}"; filename="{name}.png"\r\n'
        f"Content-Type: image/png\r\n\r\n".encode() + data + b"\r\n"
        for name, data in (("left", encode(LEFT)), ("right", encode(RIGHT)))
    )
    return parts + f"--{boundary}--\r\n".encode()


def exif_rotated_jpeg(image: np.ndarray) -> bytes:
    """JPEG stored turned 90 degrees counter-clockwise with EXIF orientation 6 (display: turn clockwise)."""
    exif = Image.Exif()
    exif[0x0112] = 6
    return encode(np.ascontiguousarray(np.rot90(image)), "JPEG", quality=97, exif=exif)


SVG = (b'<?xml version="1.0"?><svg xmlns="http://www.w3.org/2000/svg" width="96" height="64">'
       b'<rect width="96" height="64" fill="red"/></svg>')
GREY = LEFT.mean(axis=2).astype(np.uint8)


async def chunked(total: int) -> AsyncIterator[bytes]:
    """A multipart body without Content-Length, streamed in 10 kB chunks."""
    yield b'--x\r\nContent-Disposition: form-data; name="left"; filename="l.png"\r\n\r\n'
    for _ in range(total // 10_000):
        yield b"\0" * 10_000


@dataclasses.dataclass(frozen=True)
class Case:
    id: str
    status: int
    fragments: tuple[str, ...] = ()  # each must appear in the JSON detail
    path: str = "/disparity"
    params: dict[str, Any] = dataclasses.field(default_factory=lambda: dict(VALID_QUERY))
    files: dict[str, Any] | None = None
    content: bytes | Callable[[], AsyncIterator[bytes]] | None = None
    headers: dict[str, str] = dataclasses.field(default_factory=dict)
    check: Callable[[httpx.Response], None] | None = None  # for accepted inputs: what the answer holds

    def request(self, client: httpx.AsyncClient) -> Any:
        content = self.content() if callable(self.content) else self.content
        body = {"files": self.files} if content is None else {"content": content}
        if content is None and self.files is None:
            body = {"files": PAIR}
        return client.post(self.path, params=self.params, headers=self.headers, **body)


def disparity_map(response: httpx.Response) -> np.ndarray:
    """The png16 answer as float32 pixels (d x 256 -> d, 0 -> NaN)."""
    values = np.asarray(Image.open(io.BytesIO(response.content)), dtype=np.float32) / 256.0
    values[values == 0] = np.nan
    return values


def shape_is(height: int, width: int) -> Callable[[httpx.Response], None]:
    def check(response: httpx.Response) -> None:
        assert disparity_map(response).shape == (height, width)

    return check


def matches_the_pair(response: httpx.Response) -> None:
    """The decoded pair is the 64x96 texture with disparity SHIFT (so the conversion kept the content)."""
    disparity = disparity_map(response)
    assert disparity.shape == (HEIGHT, WIDTH)
    interior = disparity[8:-8, 16:-8]
    assert abs(float(np.nanmedian(interior)) - SHIFT) < 0.5, np.nanmedian(interior)


CALIB = (f"cam0=[100 0 47.5; 0 100 31.5; 0 0 1]\ncam1=[100 0 47.5; 0 100 31.5; 0 0 1]\nbaseline=100\n"
         f"width={WIDTH}\nheight={HEIGHT}\n").encode()
CAMERA = {**VALID_QUERY, "focal_px": 100, "baseline_m": 0.1}


def with_calib(data: bytes = CALIB, name: str = "calib.txt") -> dict[str, Any]:
    return {**PAIR, "calib": (name, data, "application/octet-stream")}


def has_parts(*names: str) -> Callable[[httpx.Response], None]:
    def check(response: httpx.Response) -> None:
        assert response.headers["content-type"].startswith("multipart/mixed")
        boundary = response.headers["content-type"].split("boundary=")[1].strip('"')
        found = [part.split(b'name="')[1].split(b'"')[0].decode()
                 for part in response.content.split(b"--" + boundary.encode())[1:-1]]
        assert found == list(names), found

    return check


def depth_map(response: httpx.Response) -> None:
    depth = np.load(io.BytesIO(response.content), allow_pickle=False)
    assert depth.shape == (HEIGHT, WIDTH)
    assert np.nanmedian(depth[8:-8, 16:-8]) == pytest.approx(10 / SHIFT, rel=0.1)  # f B / d, f B = 10 m px


def png16_answer(response: httpx.Response) -> None:
    assert response.headers["x-disparity-format"] == "png16"
    matches_the_pair(response)


CATALOG = [
    # --- body shape -----------------------------------------------------------------------------------------
    Case("empty body", 400, ("'left' is missing",), content=b"",
         headers={"Content-Type": "multipart/form-data; boundary=x"}),
    Case("empty body without content type", 400, ("multipart/form-data",), content=b""),
    Case("json body", 400, ("multipart/form-data", "application/json"), content=b'{"left": 1}',
         headers={"Content-Type": "application/json"}),
    Case("multipart without boundary", 400, (), content=b"--x\r\n\r\n",
         headers={"Content-Type": "multipart/form-data"}),
    Case("malformed multipart", 400, (), content=b"--x\r\ngarbage without headers",
         headers={"Content-Type": "multipart/form-data; boundary=x"}),
    Case("missing field", 400, ("'right' is missing",), files={"left": PAIR["left"]}),
    Case("text field instead of a file", 400, ("'right' must be a file",),
         files={"left": PAIR["left"], "right": (None, "right.png")}),
    Case("extra text field", 400, ("unexpected multipart field 'comment'",),
         files={**PAIR, "comment": (None, "hello")}),
    Case("left twice", 400, ("'left' is given more than once",),
         files=[("left", PAIR["left"]), ("left", ("junk.png", b"junk", "image/png")),
                ("right", PAIR["right"])]),
    Case("extra file", 400, ("files",), files={**PAIR, "third": ("third.png", encode(LEFT), "image/png")}),
    # --- not an image, or not one we decode -----------------------------------------------------------------
    Case("zero-byte left", 415, ("left", "empty"), files=files(b"", encode(RIGHT))),
    Case("zero-byte right", 415, ("right", "empty"), files=files(encode(LEFT), b"")),
    Case("truncated png", 415, ("left", "PNG"), files=files(encode(LEFT)[:600], encode(RIGHT))),
    Case("truncated jpeg", 415, ("right", "JPEG"),
         files=files(encode(LEFT, "JPEG"), encode(RIGHT, "JPEG")[:700])),
    Case("png cut inside its header", 415, ("left", "truncated header"),
         files=files(encode(LEFT)[:20], encode(RIGHT))),
    Case("bmp cut inside its header", 415, ("right", "not a readable image"),
         files=files(encode(LEFT), encode(RIGHT, "BMP")[:30])),
    Case("text posing as a png", 415, ("left", "not a readable image"),
         files=files(b"I am a PNG, trust me", encode(RIGHT))),
    Case("svg", 415, ("right", "not a readable image"), files=files(encode(LEFT), SVG)),
    Case("float tiff", 415, ("left", "unsupported pixel format F"),
         files=files(encode(Image.fromarray(GREY.astype(np.float32)), "TIFF"), encode(RIGHT))),
    # --- sizes ----------------------------------------------------------------------------------------------
    Case("png header claiming 100000 x 100000", 413, ("left", "10000000000 pixels"),
         files=files(png_claiming(100_000, 100_000), encode(RIGHT))),
    Case("zlib bomb 4000 x 4000", 413, ("right", "4000 x 4000", "exceeds the limit of 6144"),
         files=files(encode(LEFT), zlib_bomb())),
    Case("one pixel too many", 413, ("pixels",), files=files(encode(LEFT[:, :1].repeat(97, 1)),
                                                             encode(RIGHT[:, :1].repeat(97, 1)))),
    Case("mismatched sizes", 400, ("differ in size", "96 x 64", "80 x 64"),
         files=files(encode(LEFT), encode(RIGHT[:, :80]))),
    Case("1x1 images, model's range", 200, files=files(encode(LEFT[:1, :1]), encode(RIGHT[:1, :1])),
         params={}, check=shape_is(1, 1)),
    Case("1x1 images, 16 disparities", 400, ("max_disparity 16", "width 1"),
         files=files(encode(LEFT[:1, :1]), encode(RIGHT[:1, :1]))),
    Case("body over the limit by content-length", 413, ("200000 bytes",),
         files=files(b"\0" * 250_000, encode(RIGHT))),
    Case("chunked body over the limit", 413, ("200000 bytes",), content=lambda: chunked(1_000_000),
         headers={"Content-Type": "multipart/form-data; boundary=x"}),
    # --- unusual but valid pixel formats: decoded to the same 8-bit RGB content -----------------------------
    Case("grey + colour", 200, files=files(encode(GREY), encode(RIGHT.mean(axis=2).astype(np.uint8))),
         check=matches_the_pair),
    Case("grey left, colour right", 200, files=files(encode(GREY), encode(RIGHT)),
         check=shape_is(HEIGHT, WIDTH)),
    Case("16-bit png", 200, check=matches_the_pair, files=files(
        encode(Image.fromarray(GREY.astype(np.uint16) * 257)),
        encode(Image.fromarray(RIGHT.mean(axis=2).astype(np.uint16) * 257)))),
    Case("palette", 200, check=matches_the_pair,
         files=files(encode(Image.fromarray(LEFT).quantize(256)),
                     encode(Image.fromarray(RIGHT).quantize(256)))),
    Case("alpha", 200, check=matches_the_pair,
         files=files(encode(np.dstack([LEFT, np.full(GREY.shape, 40, np.uint8)])),
                     encode(np.dstack([RIGHT, np.full(GREY.shape, 200, np.uint8)])))),
    Case("cmyk jpeg", 200, check=matches_the_pair, files=files(
        encode(Image.fromarray(LEFT).convert("CMYK"), "JPEG", quality=97),
        encode(Image.fromarray(RIGHT).convert("CMYK"), "JPEG", quality=97))),
    Case("exif-rotated jpeg pair", 200, check=matches_the_pair,
         files=files(exif_rotated_jpeg(LEFT), exif_rotated_jpeg(RIGHT))),
    Case("exif-rotated left, upright right", 200, check=matches_the_pair,
         files=files(exif_rotated_jpeg(LEFT), encode(RIGHT, "JPEG", quality=97))),
    Case("rotated left without exif", 400, ("differ in size", "64 x 96"),
         files=files(encode(np.ascontiguousarray(np.rot90(LEFT))), encode(RIGHT))),
    # --- parameters -----------------------------------------------------------------------------------------
    Case("max_disparity 0", 400, ("max_disparity", "greater than or equal to 1"),
         params={"max_disparity": 0}),
    Case("max_disparity negative", 400, ("max_disparity",), params={"max_disparity": -3}),
    Case("max_disparity above the width", 400, ("max_disparity 97", "width 96"),
         params={"max_disparity": 97}),
    Case("max_disparity above the server limit", 400, ("ADSM_MAX_DISPARITY",), params={"max_disparity": 300}),
    Case("max_disparity 10^30", 400, ("max_disparity",), params={"max_disparity": 10**30}),
    Case("max_disparity not a number", 400, ("max_disparity", "integer"), params={"max_disparity": "many"}),
    Case("max_disparity fractional", 400, ("max_disparity",), params={"max_disparity": "1.5"}),
    Case("max_disparity nan", 400, ("max_disparity",), params={"max_disparity": "nan"}),
    Case("switch not a boolean", 400, ("lr_check",), params={**VALID_QUERY, "lr_check": "maybe"}),
    Case("p1 not a number", 400, ("p1",), params={**VALID_QUERY, "p1": "abc"}),
    Case("p1 inf", 400, ("p1", "finite"), params={**VALID_QUERY, "p1": "inf"}),
    Case("p2 nan", 400, ("p2",), params={**VALID_QUERY, "p2": "nan"}),
    Case("lr_check_threshold negative", 400, ("lr_check_threshold",),
         params={**VALID_QUERY, "lr_check_threshold": "-0.5"}),
    Case("lr_check_threshold nan", 400, ("lr_check_threshold",),
         params={**VALID_QUERY, "lr_check_threshold": "nan"}),
    Case("border_surface_run negative", 400, ("border_surface_run",),
         params={**VALID_QUERY, "border_surface_run": "-1"}),
    Case("border_surface_run fractional", 400, ("border_surface_run",),
         params={**VALID_QUERY, "border_surface_run": "2.5"}),
    Case("p2 absurd", 400, ("p2", "less than or equal"), params={**VALID_QUERY, "p2": "1e30"}),
    Case("focal_px missing", 400, ("focal_px",), path="/depth", params={**VALID_QUERY, "baseline_m": 0.1}),
    Case("focal_px zero", 400, ("focal_px",), path="/depth",
         params={**VALID_QUERY, "focal_px": 0, "baseline_m": 0.1}),
    Case("focal_px negative", 400, ("focal_px",), path="/depth",
         params={**VALID_QUERY, "focal_px": -700, "baseline_m": 0.1}),
    Case("focal_px absurd", 400, ("focal_px", "less than or equal"), path="/depth",
         params={**VALID_QUERY, "focal_px": "1e300", "baseline_m": 0.1}),
    Case("focal_px inf", 400, ("focal_px", "finite"), path="/depth",
         params={**VALID_QUERY, "focal_px": "inf", "baseline_m": 0.1}),
    Case("focal_px nan", 400, ("focal_px",), path="/pointcloud",
         params={**VALID_QUERY, "focal_px": "nan", "baseline_m": 0.1}),
    Case("baseline_m absurd", 400, ("baseline_m",), path="/pointcloud",
         params={**VALID_QUERY, "focal_px": 700, "baseline_m": "1e300"}),
    Case("cx -inf", 400, ("cx", "finite"), path="/pointcloud",
         params={**VALID_QUERY, "focal_px": 700, "baseline_m": 0.1, "cx": "-inf"}),
    Case("cy not a number", 400, ("cy",), path="/pointcloud",
         params={**VALID_QUERY, "focal_px": 700, "baseline_m": 0.1, "cy": "middle"}),
    Case("misspelt parameter", 400, ("unknown query parameter 'max_disparty'", "max_disparity"),
         params={"max_disparty": 16}),
    Case("unknown format", 400, ("format",), params={**VALID_QUERY, "format": "jpeg"}),
    Case("format of another route", 400, ("format",), path="/depth",
         params={**VALID_QUERY, "focal_px": 700, "baseline_m": 0.1, "format": "color"}),
    # --- issue 15: sizes that pass the pixel limit but not the work or memory model, containers, params -----
    # Header-only PNGs (decoding them would fail): a 413 shows the plan was judged before decoding.
    Case("one row as wide as the pixel limit", 413,
         ("padded pixels", "square image of the pixel limit (ADSM_MAX_PIXELS)"),
         files=files(png_claiming(HEIGHT * WIDTH, 1), png_claiming(HEIGHT * WIDTH, 1))),
    Case("one column as tall as the pixel limit", 413, ("padded pixels",), params={},
         files=files(png_claiming(1, HEIGHT * WIDTH), png_claiming(1, HEIGHT * WIDTH))),
    Case("eight rows", 413, ("padded pixels",),
         files=files(png_claiming(HEIGHT * WIDTH // 8, 8), png_claiming(HEIGHT * WIDTH // 8, 8))),
    Case("ico holding a huge png", 415, ("left", "refused format"),
         files=files(ico_holding(png_claiming(13000, 13000)), encode(RIGHT))),
    Case("icns holding a huge png", 415, ("right", "refused format"),
         files=files(encode(LEFT), icns_holding(png_claiming(13000, 13000)))),
    Case("repeated query parameter", 400, ("'max_disparity' is given more than once",),
         params=[("max_disparity", 16), ("max_disparity", 32)]),
    Case("fill without lr_check", 400, ("fill=true needs lr_check=true",),
         params={**VALID_QUERY, "lr_check": "false", "fill": "true"}),
    Case("lr_check off, fill unset", 200, params={**VALID_QUERY, "lr_check": "false"},
         check=shape_is(64, 96)),
    Case("focal_px and baseline_m tiny", 400, ("focal_px", "baseline_m"), path="/depth",
         params={**VALID_QUERY, "focal_px": "1e-30", "baseline_m": "1e-30"}),
    # --- issue 13 item 3: search start, maps, camera, calibration file -------------------------------------
    Case("min_disparity at the width", 400, ("min_disparity 96", "-95..95"),
         params={**VALID_QUERY, "min_disparity": 96}),
    Case("min_disparity + range beyond the width", 400, ("max_disparity 16 exceeds the image width 96",
                                                         "from min_disparity 90"),
         params={**VALID_QUERY, "min_disparity": 90}),
    Case("min_disparity fractional", 400, ("min_disparity",), params={**VALID_QUERY, "min_disparity": "2.5"}),
    Case("min_disparity 10^30", 400, ("min_disparity",), params={**VALID_QUERY, "min_disparity": 10**30}),
    Case("negative min_disparity", 200, params={**VALID_QUERY, "min_disparity": -8}, check=matches_the_pair),
    Case("confidence not a boolean", 400, ("confidence",), params={**VALID_QUERY, "confidence": "sometimes"}),
    Case("confidence on /depth", 400, ("unknown query parameter 'confidence'",), path="/depth",
         params={**CAMERA, "confidence": "true"}),
    Case("confidence and validity parts", 200,
         params={**VALID_QUERY, "confidence": "true", "validity": "true"},
         check=has_parts("disparity", "validity", "confidence")),
    Case("colormap_range without format=color", 400, ("colormap_range", "format=color"),
         params={**VALID_QUERY, "colormap_range": "0,16"}),
    Case("colormap_range reversed", 400, ("below",),
         params={**VALID_QUERY, "format": "color", "colormap_range": "16,0"}),
    Case("colormap_range not numbers", 400, ("colormap_range",),
         params={**VALID_QUERY, "format": "color", "colormap_range": "near,far"}),
    Case("colormap_range absurd", 400, ("colormap_range", "finite"),
         params={**VALID_QUERY, "format": "color", "colormap_range": "1" + "0" * 30 + ",2" + "0" * 30}),
    Case("colormap_range too long", 400, ("colormap_range",),
         params={**VALID_QUERY, "format": "color", "colormap_range": "1" * 70 + ",2"}),
    Case("max_depth zero", 400, ("max_depth", "greater than 0"), path="/pointcloud",
         params={**CAMERA, "max_depth": 0}),
    Case("max_depth inf", 400, ("max_depth", "finite"), path="/pointcloud",
         params={**CAMERA, "max_depth": "inf"}),
    Case("drop_filled not a boolean", 400, ("drop_filled",), path="/depth",
         params={**CAMERA, "drop_filled": "some"}),
    Case("doffs nan", 400, ("doffs",), path="/depth", params={**CAMERA, "doffs": "nan"}),
    Case("doffs on /disparity", 400, ("unknown query parameter 'doffs'",),
         params={**VALID_QUERY, "doffs": 2}),
    Case("no camera", 400, ("focal_px and baseline_m", "calib"), path="/depth"),
    Case("calib file and focal_px", 400, ("calib file or focal_px, baseline_m", "not both"), path="/depth",
         params=CAMERA, files=with_calib()),
    Case("cx beside a calib file", 400, ("cx", "not both"), path="/pointcloud",
         params={**VALID_QUERY, "cx": 3}, files=with_calib()),
    Case("calib_units without a file", 400, ("calib_units", "'calib'"), path="/depth",
         params={**CAMERA, "calib_units": "mm"}),
    Case("calib_units unknown", 400, ("calib_units",), path="/depth",
         params={**VALID_QUERY, "calib_units": "inch"}, files=with_calib()),
    Case("calib_rectified not a boolean", 400, ("calib_rectified",), path="/depth",
         params={**VALID_QUERY, "calib_rectified": "yes please"}, files=with_calib()),
    Case("diagnostics not a boolean", 400, ("diagnostics",), params={**VALID_QUERY, "diagnostics": "maybe"}),
    Case("calib not text", 400, ("calib.txt: not a text file",), path="/depth",
         files=with_calib(b"\xff\xd8\xff\xe0 a jpeg?")),
    Case("calib of no known format", 400, ("notes.txt: unknown calibration format",), path="/depth",
         files=with_calib(b"f = 700 px, B = 10 cm", "notes.txt")),
    Case("calib malformed opencv", 400, ("rig.yml (OpenCV)",), path="/depth",
         files=with_calib(b"%YAML:1.0\n---\nP1: [1, 2\n  : : ]]\n", "rig.yml")),
    Case("calib for other images", 400, ("calibrated for 96x50 images, got 96x64",), path="/depth",
         files=with_calib(CALIB.replace(b"height=64", b"height=50"))),
    Case("calib as a text field", 400, ("'calib' must be a file",), path="/depth",
         files={**PAIR, "calib": (None, CALIB.decode())}),
    Case("calib twice", 400, ("files",), path="/depth",
         files=[*PAIR.items(), ("calib", ("a.txt", CALIB, "text/plain")),
                ("calib", ("b.txt", CALIB, "text/plain"))]),
    Case("calib on /disparity", 200, files=with_calib(), check=matches_the_pair),
    Case("calib on /depth", 200, path="/depth", params=VALID_QUERY, files=with_calib(), check=depth_map),
    Case("camera by hand on /depth", 200, path="/depth", params=CAMERA, check=depth_map),
    Case("upper-case multipart media type", 200, content=multipart_body(),
         headers={"Content-Type": "MULTIPART/FORM-DATA; boundary=x"}, check=png16_answer),
    # --- Accept: anything unknown gets the documented default, errors stay JSON -----------------------------
    Case("foreign accept", 200, headers={"Accept": "application/json"}, check=png16_answer),
    Case("malformed accept", 200, headers={"Accept": ";;q=x, /,*/*;q=abc"}, check=png16_answer),
    Case("error under a foreign accept", 400, ("max_disparity",), params={"max_disparity": 0},
         headers={"Accept": "text/html"}),
]


@pytest.fixture(scope="module")
def anyio_backend() -> str:
    return "asyncio"


@pytest.fixture(scope="module")
async def app_client():
    app = create_app(SETTINGS)
    async with ready_client(app) as client:
        yield app, client


def test_catalog_is_large_enough() -> None:
    assert len(CATALOG) >= 30
    assert len({case.id for case in CATALOG}) == len(CATALOG)


@pytest.mark.parametrize("case", CATALOG, ids=[case.id for case in CATALOG])
async def test_bad_input(app_client, case: Case) -> None:
    app, client = app_client
    response = await case.request(client)
    assert response.status_code == case.status, response.text[:300]
    if case.status >= 400:
        assert response.headers["content-type"] == "application/json"
        detail = response.json()["detail"]
        assert isinstance(detail, str) and detail, response.text
        for fragment in case.fragments:
            assert fragment in detail, detail
        # A clear sentence, not an object's repr or a traceback.
        assert " object at 0x" not in detail and "Traceback" not in detail, detail
    elif case.check is not None:
        case.check(response)

    # The server stays up and nothing is left behind: the next valid request succeeds at once.
    assert (await client.get("/healthz")).status_code == 200
    inference = app.state.inference
    assert inference.slot.waiting == 0 and not inference.slot.running
    valid = await client.post("/disparity", params=VALID_QUERY, files=PAIR)
    assert valid.status_code == 200, valid.text
    matches_the_pair(valid)
