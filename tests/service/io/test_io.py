"""Image decoding and disparity codecs."""

from __future__ import annotations

import io
import struct
import zlib

import numpy as np
import pytest
from PIL import Image

from service.io import (
    ALLOWED_FORMATS,
    ImageDecodeError,
    ImageTooLargeError,
    colorize,
    encode_disparity,
    format_for_path,
    image_size,
    media_type,
    read_disparity,
    read_image,
    read_pair,
    write_disparity,
)
from service.io.colormap import TURBO

RNG = np.random.default_rng(7)


def _encode(image: Image.Image, fmt: str, **options) -> bytes:
    buffer = io.BytesIO()
    image.save(buffer, format=fmt, **options)
    return buffer.getvalue()


# ---------------------------------------------------------------- images


@pytest.mark.parametrize("fmt", ["PNG", "PPM", "TIFF", "BMP"])
def test_rgb_lossless_formats_round_trip(fmt):
    rgb = RNG.integers(0, 256, (7, 5, 3), dtype=np.uint8)
    decoded = read_image(_encode(Image.fromarray(rgb), fmt))
    assert decoded.dtype == np.uint8 and decoded.flags.c_contiguous
    np.testing.assert_array_equal(decoded, rgb)


def test_jpeg_decodes_close_to_source():
    rgb = np.full((16, 16, 3), (200, 100, 50), np.uint8)
    decoded = read_image(_encode(Image.fromarray(rgb), "JPEG", quality=95))
    assert decoded.shape == (16, 16, 3)
    assert np.abs(decoded.astype(int) - rgb).max() <= 3


@pytest.mark.parametrize("fmt", ["PNG", "PPM"])
def test_grey_expanded_to_three_channels(fmt):
    grey = RNG.integers(0, 256, (4, 6), dtype=np.uint8)
    decoded = read_image(_encode(Image.fromarray(grey), fmt))
    assert decoded.shape == (4, 6, 3)
    for channel in range(3):
        np.testing.assert_array_equal(decoded[:, :, channel], grey)


@pytest.mark.parametrize("fmt", ["PNG", "TIFF"])
def test_sixteen_bit_grey_using_all_sixteen_bits_is_scaled_by_65535(fmt):
    samples = np.array([[0, 255, 256, 511], [32768, 40000, 65280, 65535]], np.uint16)
    decoded = read_image(_encode(Image.fromarray(samples), fmt))
    np.testing.assert_array_equal(decoded[:, :, 1], np.rint(samples * 255.0 / 65535).astype(np.uint8))
    assert np.abs(decoded[:, :, 1].astype(int) - (samples >> 8)).max() <= 1  # as the high byte, rounded


def _png_with_sbit(samples: np.ndarray, bits: int) -> bytes:
    """A 16-bit grey PNG of ``samples`` with an sBIT chunk (Pillow writes none) inserted after IHDR."""
    encoded = _encode(Image.fromarray(samples), "PNG")
    body = bytes([bits])
    chunk = len(body).to_bytes(4, "big") + b"sBIT" + body + zlib.crc32(b"sBIT" + body).to_bytes(4, "big")
    return encoded[:33] + chunk + encoded[33:]


@pytest.mark.parametrize("fmt", ["PNG", "TIFF"])
def test_twelve_bit_grey_keeps_its_levels(fmt):
    ramp = np.tile(np.arange(0, 4096, 8, dtype=np.uint16), (4, 1))  # Mono12 in a 16-bit file
    grey = read_image(_encode(Image.fromarray(ramp), fmt))[:, :, 0]
    np.testing.assert_array_equal(grey[0], np.rint(ramp[0] * 255.0 / 4095).astype(np.uint8))
    assert grey[0, -1] == 255 and len(np.unique(grey)) > 200  # >> 8 left 16 levels


def test_sbit_chunk_names_the_depth_and_a_pair_shares_one():
    dark = np.array([[0, 1000, 2000]], np.uint16)  # 11 bits used of a 12-bit sensor
    assert read_image(_png_with_sbit(dark, 12))[0, :, 0].tolist() == [0, 62, 125]  # x 255 / 4095
    assert read_image(_encode(Image.fromarray(dark), "PNG"))[0, :, 0].tolist() == [0, 125, 249]  # / 2047
    bright = np.array([[0, 1000, 4000]], np.uint16)
    left, right = read_pair(_encode(Image.fromarray(dark), "PNG"), _encode(Image.fromarray(bright), "PNG"))
    assert left[0, 1, 0] == right[0, 1, 0] == 62  # both / 4095: equal samples stay equal levels


def test_sixteen_bit_colour_png_is_refused():
    raw = b"".join(b"\0" + np.full((8, 3), 1000, ">u2").tobytes() for _ in range(8))

    def chunk(kind: bytes, body: bytes) -> bytes:
        return len(body).to_bytes(4, "big") + kind + body + zlib.crc32(kind + body).to_bytes(4, "big")

    ihdr = (8).to_bytes(4, "big") * 2 + bytes([16, 2, 0, 0, 0])
    rgb16 = (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", zlib.compress(raw))
             + chunk(b"IEND", b""))
    with pytest.raises(ImageDecodeError, match="16-bit colour PNG would lose precision"):
        read_image(rgb16, name="left")


def test_sixteen_bit_pgm_scaled_not_clipped():
    samples = np.array([[65535, 256, 1000, 0]], ">u2")
    pgm = b"P5\n4 1\n65535\n" + samples.tobytes()
    # Pillow scales maxval to 16 bits; the samples use all 16, so / 65535 (rounded).
    np.testing.assert_array_equal(read_image(pgm)[0, :, 0], [255, 1, 4, 0])


def test_sixteen_bit_rgb_ppm_scaled_not_clipped():
    # Pillow reduces 16-bit colour itself, rounding x * 255 / 65535 (within one level of >> 8).
    samples = np.array([[65535, 0, 256], [1000, 2000, 30000]], ">u2")
    ppm = b"P6\n2 1\n65535\n" + samples.tobytes()
    decoded = read_image(ppm)[0].astype(int)
    np.testing.assert_array_equal(decoded, np.round(samples.astype(float) / 257))
    assert np.abs(decoded - (samples.astype(int) >> 8)).max() <= 1


def test_alpha_dropped_not_composited():
    rgba = RNG.integers(0, 256, (3, 4, 4), dtype=np.uint8)
    rgba[..., 3] = 0  # fully transparent: compositing would give black or white
    decoded = read_image(_encode(Image.fromarray(rgba), "PNG"))
    np.testing.assert_array_equal(decoded, rgba[..., :3])


def test_grey_alpha_dropped():
    la = Image.fromarray(np.array([[[10, 0], [20, 255]]], np.uint8), mode="LA")
    np.testing.assert_array_equal(read_image(_encode(la, "PNG"))[0], [[10] * 3, [20] * 3])


def test_palette_converted():
    image = Image.new("P", (2, 1))
    image.putpalette([255, 0, 0, 0, 0, 255] + [0] * 762)
    image.putpixel((1, 0), 1)
    np.testing.assert_array_equal(read_image(_encode(image, "PNG"))[0], [[255, 0, 0], [0, 0, 255]])


def test_cmyk_converted():
    cmyk = Image.new("CMYK", (1, 1), (0, 255, 255, 0))  # pure red in CMYK
    np.testing.assert_array_equal(read_image(_encode(cmyk, "TIFF"))[0, 0], [255, 0, 0])


def test_exif_orientation_applied():
    rgb = np.zeros((2, 3, 3), np.uint8)
    rgb[0, 0] = 255  # a marker in the top-left corner
    exif = Image.Exif()
    exif[0x0112] = 6  # "rotate 90 CW to display"
    decoded = read_image(_encode(Image.fromarray(rgb), "PNG", exif=exif))
    assert decoded.shape == (3, 2, 3)
    assert decoded[0, 1].tolist() == [255, 255, 255]


def test_read_from_path(tmp_path):
    rgb = RNG.integers(0, 256, (3, 3, 3), dtype=np.uint8)
    Image.fromarray(rgb).save(tmp_path / "x.png")
    np.testing.assert_array_equal(read_image(tmp_path / "x.png"), rgb)
    np.testing.assert_array_equal(read_image(str(tmp_path / "x.png")), rgb)


def test_missing_path_is_file_not_found(tmp_path):
    with pytest.raises(FileNotFoundError):
        read_image(tmp_path / "missing.png")


@pytest.mark.parametrize("data", [b"", b"not an image at all", b"\x89PNG\r\n\x1a\n" + b"\0" * 20])
def test_garbage_is_a_decode_error(data):
    with pytest.raises(ImageDecodeError, match="left"):
        read_image(data, name="left")


def test_truncated_png_is_a_decode_error():
    png = _encode(Image.fromarray(RNG.integers(0, 256, (64, 64, 3), dtype=np.uint8)), "PNG")
    with pytest.raises(ImageDecodeError):
        read_image(png[: len(png) // 2])


@pytest.mark.parametrize("fmt", ["PNG", "BMP", "WEBP"])
def test_image_cut_inside_its_header_is_a_decode_error(fmt):
    # Pillow's open() raises a bare OSError for these ("Truncated File Read" for a PNG cut inside IHDR,
    # "Unsupported BMP ..." or "could not create decoder object" for WebP): the HTTP service answered 500.
    data = _encode(Image.fromarray(RNG.integers(0, 256, (8, 8, 3), dtype=np.uint8)), fmt)
    for size in (16, 20, 28, 30):
        for read in (read_image, image_size):
            with pytest.raises(ImageDecodeError, match="left: not a readable image"):
                read(data[:size], name="left")


def test_float_image_refused():
    with pytest.raises(ImageDecodeError, match="unsupported pixel format F"):
        read_image(_encode(Image.fromarray(np.ones((2, 2), np.float32)), "TIFF"))


def test_pixel_limit_checked_before_decoding():
    # A header announcing 8000 x 4000 followed by no pixel data: refused from the header alone.
    header = b"P5\n8000 4000\n255\n"
    with pytest.raises(ImageTooLargeError, match="32000000 pixels exceeds the limit of 1000000"):
        read_image(header, max_pixels=1_000_000)
    assert issubclass(ImageTooLargeError, ImageDecodeError)
    assert issubclass(ImageDecodeError, ValueError)


def test_decompression_bomb_without_limit_is_too_large():
    with pytest.raises(ImageTooLargeError, match="decompression bomb"):
        read_image(b"P5\n20000 20000\n255\n")


def test_pixel_limit_allows_exact_size():
    rgb = np.zeros((10, 10, 3), np.uint8)
    assert read_image(_encode(Image.fromarray(rgb), "PNG"), max_pixels=100).shape == (10, 10, 3)


# ---------------------------------------------------------------- disparity codecs


def _disparity_on_png16_grid(shape=(9, 13)) -> np.ndarray:
    values = RNG.integers(1, 65536, shape).astype(np.float32) / 256
    values[RNG.random(shape) < 0.2] = np.nan
    return values


def test_png16_round_trip_bit_exact(tmp_path):
    disparity = _disparity_on_png16_grid()
    write_disparity(tmp_path / "d.png", disparity, "png16")
    back = read_disparity(tmp_path / "d.png")
    assert back.dtype == np.float32
    np.testing.assert_array_equal(np.isnan(back), np.isnan(disparity))
    assert back.tobytes() == disparity.tobytes()  # identical bits, NaNs included


def test_png16_stores_kitti_convention():
    disparity = np.array([[1.5, np.nan, np.inf, -2.0, 0.0, 300.0, 1e-4]], np.float32)
    with Image.open(io.BytesIO(encode_disparity(disparity, "png16"))) as image:
        stored = np.asarray(image)
    assert stored.dtype == np.uint16
    np.testing.assert_array_equal(stored[0], [384, 0, 0, 0, 0, 65535, 1])


def test_png16_reads_kitti_ground_truth_style_file(tmp_path):
    Image.fromarray(np.array([[0, 256, 14080]], np.uint16)).save(tmp_path / "gt.png")
    np.testing.assert_array_equal(read_disparity(tmp_path / "gt.png"), [[np.nan, 1.0, 55.0]])


def test_pfm_round_trip_bit_exact(tmp_path):
    disparity = RNG.normal(30, 10, (6, 11)).astype(np.float32)
    disparity[2, 3] = np.nan
    disparity[0, 0] = 0.0
    write_disparity(tmp_path / "d.pfm", disparity, "pfm")
    back = read_disparity(tmp_path / "d.pfm")
    assert back.tobytes() == disparity.tobytes()


def test_pfm_layout_little_endian_bottom_up_inf_invalid():
    disparity = np.array([[1.0, 2.0], [3.0, np.nan]], np.float32)
    data = encode_disparity(disparity, "pfm")
    assert data.startswith(b"Pf\n2 2\n-1.0\n")
    body = np.frombuffer(data[len(b"Pf\n2 2\n-1.0\n") :], "<f4")
    np.testing.assert_array_equal(body, [3.0, np.inf, 1.0, 2.0])


def test_pfm_big_endian_read(tmp_path):
    rows_bottom_up = np.array([[3.0, np.inf, 5.5], [1.0, 2.0, 4.25]], ">f4")
    (tmp_path / "be.pfm").write_bytes(b"Pf\n3 2\n1.0\n" + rows_bottom_up.tobytes())
    np.testing.assert_array_equal(read_disparity(tmp_path / "be.pfm"), [[1.0, 2.0, 4.25], [3.0, np.nan, 5.5]])


def test_pfm_colour_takes_first_channel_and_tolerates_trailing_newline(tmp_path):
    pixels = struct.pack("<6f", 7.0, 0.0, 0.0, 8.0, 0.0, 0.0)
    (tmp_path / "c.pfm").write_bytes(b"PF\n2 1\n-1\n" + pixels + b"\n")
    np.testing.assert_array_equal(read_disparity(tmp_path / "c.pfm"), [[7.0, 8.0]])


def test_pfm_truncated_refused(tmp_path):
    (tmp_path / "t.pfm").write_bytes(b"Pf\n4 4\n-1.0\n" + b"\0" * 12)
    with pytest.raises(ValueError, match="truncated PFM"):
        read_disparity(tmp_path / "t.pfm")


def test_npy_round_trip(tmp_path):
    disparity = RNG.normal(20, 5, (5, 4)).astype(np.float32)
    disparity[1, 1] = np.nan
    disparity[0, 2] = np.inf  # stored as NaN: npy's invalid marker
    write_disparity(tmp_path / "d.npy", disparity, "npy")
    stored = np.load(tmp_path / "d.npy")
    assert stored.dtype == np.float32 and np.isnan(stored[0, 2])
    back = read_disparity(tmp_path / "d.npy")
    expected = disparity.copy()
    expected[0, 2] = np.nan
    assert back.tobytes() == expected.tobytes()


def test_write_to_stream():
    buffer = io.BytesIO()
    write_disparity(buffer, np.ones((2, 2), np.float32), "npy")
    assert buffer.getvalue() == encode_disparity(np.ones((2, 2), np.float32), "npy")


def test_bad_inputs_refused(tmp_path):
    with pytest.raises(ValueError, match="unknown disparity format"):
        encode_disparity(np.ones((2, 2)), "jpeg")
    with pytest.raises(ValueError, match="2-D real array"):
        encode_disparity(np.ones((2, 2, 3)), "png16")
    (tmp_path / "x.txt").write_bytes(b"hello")
    with pytest.raises(ValueError, match="not a png16, PFM or npy"):
        read_disparity(tmp_path / "x.txt")
    Image.fromarray(np.zeros((2, 2, 3), np.uint8)).save(tmp_path / "rgb.png")
    with pytest.raises(ValueError, match="16-bit grey"):
        read_disparity(tmp_path / "rgb.png")


def test_formats_and_media_types():
    assert format_for_path("out/disp.PNG") == "png16"
    assert format_for_path("d.pfm") == "pfm"
    assert format_for_path("d.npy") == "npy"
    with pytest.raises(ValueError, match=r"\.png, \.npy or \.pfm"):
        format_for_path("d.jpg")
    assert media_type("png16") == "image/png"
    assert media_type("color") == "image/png"
    assert media_type("pfm") == "image/x-portable-floatmap"


# ---------------------------------------------------------------- colour map


def test_colorize_invalid_black_and_range_ends():
    disparity = np.array([[10.0, 20.0, np.nan, 0.0, 15.0]], np.float32)
    rgb = colorize(disparity)
    assert rgb.dtype == np.uint8 and rgb.shape == (1, 5, 3)
    np.testing.assert_array_equal(rgb[0, 0], TURBO[0])
    np.testing.assert_array_equal(rgb[0, 1], TURBO[-1])
    np.testing.assert_array_equal(rgb[0, 2:4], 0)


def test_turbo_is_blue_to_red_and_perceptually_ordered():
    far, middle, last = TURBO[25].astype(int), TURBO[128].astype(int), TURBO[-1].astype(int)
    assert far[2] > far[0] + 100  # far: blue
    assert last[0] > last[2]  # near: red
    assert middle[1] > 200  # green-yellow centre
    luminance = TURBO.astype(float) @ [0.299, 0.587, 0.114]
    assert luminance.argmax() not in (0, 255)  # dark ends, bright middle: no black/white extreme colours


def test_color_png_decodes_to_colorize():
    disparity = RNG.uniform(1, 64, (8, 8)).astype(np.float32)
    decoded = read_image(encode_disparity(disparity, "color"))
    np.testing.assert_array_equal(decoded, colorize(disparity))


def test_colorize_fixed_range_clips():
    rgb = colorize(np.array([[0.5, 100.0]], np.float32), min_disparity=1, max_disparity=64)
    np.testing.assert_array_equal(rgb[0, 0], TURBO[0])
    np.testing.assert_array_equal(rgb[0, 1], TURBO[-1])


# --- issue 15: containers whose reader decodes inside open() -----------------------------------------------


def _ico_holding(image: bytes) -> bytes:
    entry = bytes([0, 0, 0, 0]) + (1).to_bytes(2, "little") + (32).to_bytes(2, "little")
    return b"\0\0\1\0\1\0" + entry + len(image).to_bytes(4, "little") + (22).to_bytes(4, "little") + image


@pytest.mark.parametrize("container", ["ICO", "ICNS"])
def test_containers_that_decode_in_open_are_refused_without_running_their_reader(monkeypatch, container):
    from PIL import IcnsImagePlugin, IcoImagePlugin

    def never(self):
        raise AssertionError(f"{container} reader ran")

    monkeypatch.setattr(IcoImagePlugin.IcoImageFile, "_open", never)
    monkeypatch.setattr(IcnsImagePlugin.IcnsImageFile, "_open", never)
    png = _encode(Image.new("L", (64, 64)), "PNG")
    data = _ico_holding(png) if container == "ICO" else (
        b"icns" + (16 + len(png)).to_bytes(4, "big") + b"ic10" + (8 + len(png)).to_bytes(4, "big") + png
    )
    for read in (read_image, image_size):
        with pytest.raises(ImageDecodeError, match="refused format"):
            read(data, max_pixels=2_100_000, name="left")


@pytest.mark.parametrize("fmt", ["PNG", "JPEG", "PPM", "TIFF", "BMP", "WEBP", "GIF"])
def test_allowed_formats_open_without_decoding(fmt):
    # The pixel limit is judged on the header: open() must not have decoded anything yet.
    data = _encode(Image.fromarray(RNG.integers(0, 256, (40, 30, 3), dtype=np.uint8)), fmt)
    assert fmt in ALLOWED_FORMATS
    with Image.open(io.BytesIO(data), formats=ALLOWED_FORMATS) as image:
        assert image._im is None, fmt
    assert image_size(data) == (40, 30)


def test_image_size_follows_exif_orientation():
    exif = Image.Exif()
    exif[0x0112] = 6  # displayed turned 90 degrees: width and height swap
    data = _encode(Image.new("RGB", (30, 10)), "JPEG", exif=exif)
    assert image_size(data) == read_image(data).shape[:2] == (30, 10)
