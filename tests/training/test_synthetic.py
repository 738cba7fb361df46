"""Synthetic stereo generator: exact geometry and occlusions, determinism, ranges, textures, camera."""

from __future__ import annotations

import numpy as np
import pytest

from service.datasets import StereoSample
from training.data.synthetic.generator import (
    PHOTO_SHARE,
    VALIDATION_CONFIG,
    VALIDATION_SEED,
    SyntheticConfig,
    downsampled,
    generate,
    random_scene,
    render_scene,
    validation_split,
)
from training.data.synthetic.photometric import Photometric, apply_camera
from training.data.synthetic.scene import (
    DOME_MAX_SLOPE,
    Dome,
    Ellipse,
    Everywhere,
    Layer,
    Plane,
    Polygon,
    Segment,
    Shaded,
    render,
)
from training.data.synthetic.textures import PHOTOS, ImageTexture, load_photos, minified


class SurfaceCoordinates:
    """Paints each surface point with its own left-image coordinates, so a view shows what it hit."""

    def sample(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        return np.stack([x, y, np.zeros_like(x)], axis=1).astype(np.float32)


def square(x0: float, y0: float, x1: float, y1: float) -> Polygon:
    return Polygon(np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]], dtype=np.float64))


def test_fronto_parallel_square_occludes_exactly_its_disparity_step():
    paint = SurfaceCoordinates()
    layers = [Layer(Plane(0, 0, 5), Everywhere(), paint),
              Layer(Plane(0, 0, 20), square(40, 10, 80, 30), paint)]
    scene = render(layers, height=40, width=120)
    x = np.arange(120)
    expected_rows_with_square = (x < 5) | ((x >= 25) & (x < 40))   # band 20 - 5 wide left of the square
    for row in range(40):
        expected = expected_rows_with_square if 10 <= row < 30 else x < 5
        np.testing.assert_array_equal(scene.occluded[row], expected, err_msg=f"row {row}")
    assert np.all(scene.disparity[10:30, 40:80] == 20) and np.all(scene.disparity[:10] == 5)
    # The right view sees the square shifted by its disparity: x_right in [20, 60).
    assert np.all(scene.disparity_right[10:30, 20:60] == 20)
    assert np.all(scene.disparity_right[10:30, 60:] == 5) and np.all(scene.disparity_right[10:30, :20] == 5)


def test_right_view_hits_the_surface_its_disparity_says():
    paint = SurfaceCoordinates()
    layers = [Layer(Plane(0.08, -0.05, 12.3), Everywhere(), paint),
              Layer(Plane(-0.2, 0.1, 40.7), square(30, 5, 70, 35), paint),
              Layer(Plane(0.0, 0.02, 30.0), Segment(90, 0, 95, 40, 1.5), paint)]
    scene = render(layers, height=40, width=128)
    columns = np.arange(128)[None, :]
    # Right pixel x_r shows the surface point at left abscissa x_r + d_right, on the same row.
    np.testing.assert_allclose(scene.right[..., 0], columns + scene.disparity_right, atol=1e-3)
    np.testing.assert_allclose(scene.right[..., 1], np.arange(40)[:, None] + 0 * columns, atol=1e-4)
    np.testing.assert_allclose(scene.left[..., 0], columns + 0.0 * scene.disparity, atol=1e-4)
    # Slanted plane: the disparity seen on the right equals the plane at the left point it came from.
    x_left = scene.right[..., 0]
    y = np.arange(40, dtype=np.float32)[:, None]
    on_background = np.isclose(scene.disparity_right, layers[0].surface.at(x_left, y), atol=1e-3)
    assert on_background.mean() > 0.5


def test_visible_left_pixels_find_their_surface_in_the_right_view():
    paint = SurfaceCoordinates()
    layers = [Layer(Plane(0.05, 0, 8.25), Everywhere(), paint),
              Layer(Plane(0, 0, 33.5), square(50, 0, 90, 20), paint)]
    scene = render(layers, height=20, width=128)
    for row in (3, 17):
        visible = np.flatnonzero(~scene.occluded[row])
        x_right = visible - scene.disparity[row, visible]
        # Interpolating the right view at the match gives back the pixel, away from the right view's edges.
        edges = np.flatnonzero(np.abs(np.diff(scene.disparity_right[row])) > 0.5) + 0.5
        smooth = np.abs(np.subtract.outer(x_right, edges)).min(axis=1) > 1
        seen = np.interp(x_right[smooth], np.arange(128), scene.right[row, :, 0])
        assert smooth.sum() > 60
        np.testing.assert_allclose(seen, visible[smooth], atol=1e-3)


def test_a_dome_is_ray_cast_exactly_in_both_views():
    """A curved surface has no closed-form right-view intersection: the fixed point must land on the
    surface point whose disparity the right view reports, and the left view must find it again."""
    paint = SurfaceCoordinates()
    dome = Dome(Plane(0.05, -0.02, 20.0), cx=64.0, cy=20.0, rx=30.0, ry=14.0, angle=0.4, height=3.0)
    layers = [Layer(Plane(0.0, 0.0, 6.0), Everywhere(), paint),
              Layer(dome, Ellipse(64.0, 20.0, 30.0, 14.0, 0.4), paint)]
    scene = render(layers, height=40, width=128)
    x_left, y = scene.right[..., 0], np.arange(40, dtype=np.float32)[:, None] + 0 * scene.right[..., 0]
    on_dome = np.isclose(scene.disparity_right, dome.at(x_left, y), atol=1e-3) & (scene.disparity_right > 10)
    assert on_dome.sum() > 300
    # x_r = x - d(x, y) on every right pixel that sees the dome, and the bulge is really there.
    columns = np.broadcast_to(np.arange(128, dtype=np.float32), (40, 128))
    np.testing.assert_allclose(columns[on_dome], (x_left - dome.at(x_left, y))[on_dome], atol=2e-3)
    assert scene.disparity[20, 64] == pytest.approx(dome.plane.at(64.0, 20.0) + 3.0, abs=1e-4)
    row = 20
    visible = np.flatnonzero(~scene.occluded[row] & (scene.disparity[row] > 10))
    seen = np.interp(visible - scene.disparity[row, visible], np.arange(128), scene.right[row, :, 0])
    np.testing.assert_allclose(seen[2:-2], visible[2:-2], atol=2e-2)


def test_domes_refuse_slopes_the_ray_casting_cannot_follow():
    with pytest.raises(ValueError, match="too steep"):
        Dome(Plane(0.1, 0, 10), cx=0, cy=0, rx=10, ry=4, angle=0, height=1.0)   # 0.1 + 2 / 4 > 0.5
    Dome(Plane(0.1, 0, 10), cx=0, cy=0, rx=10, ry=4, angle=0, height=0.79)
    assert DOME_MAX_SLOPE < 1


def test_shading_is_the_same_paint_in_both_views_and_darkens_away_from_the_light():
    dome = Dome(Plane(0, 0, 10), cx=0.0, cy=0.0, rx=20.0, ry=20.0, angle=0.0, height=2.0)
    lit = Shaded(SurfaceCoordinates(), dome, relief=1.0, light=(1.0, 0.0, 0.0), ambient=0.2)
    flat = ImageTexture(np.ones((4, 4, 3), dtype=np.float32))
    shaded = Shaded(flat, dome, relief=1.0, light=(1.0, 0.0, 0.0), ambient=0.2)
    x, y = np.array([15.0, -15.0, 0.0, 30.0]), np.zeros(4)
    brightness = shaded.sample(x, y)[:, 0]
    # Facing the light (x > 0 side: normal leans to +x) bright, facing away only ambient, outside flat.
    assert brightness[0] > 0.5 and brightness[1] == pytest.approx(0.2) and brightness[3] == pytest.approx(0.2)
    assert lit.sample(x, y).dtype == np.float32


@pytest.mark.torch  # the train extra: scikit-image's photos paint the scenes
def test_curved_surfaces_leave_the_rest_of_the_scene_and_the_split_unchanged():
    config = SyntheticConfig(height=96, width=192, max_disparity=48)
    curved = SyntheticConfig(height=96, width=192, max_disparity=48, curved_surfaces=1.0)
    plain_layers = random_scene(np.random.default_rng(3), height=96, width=192, max_disparity=48,
                                photo_probability=0.35)
    curved_layers = random_scene(np.random.default_rng(3), height=96, width=192, max_disparity=48,
                                 photo_probability=0.35, curved_surfaces=1.0,
                                 shapes=np.random.default_rng([3, 1]))
    assert len(plain_layers) == len(curved_layers)
    domes = [c for p, c in zip(plain_layers, curved_layers, strict=True) if isinstance(c.surface, Dome)]
    assert domes and all(d.surface.plane in [p.surface for p in plain_layers] for d in domes)
    assert all(c.surface == p.surface for p, c in zip(plain_layers, curved_layers, strict=True)
               if not isinstance(c.surface, Dome))
    for seed in range(4):
        sample = generate(seed, curved)
        assert np.nanmin(sample.disparity) >= 0 and np.nanmax(sample.disparity) <= 48 + 1e-3
    assert not np.array_equal(generate(0, config).disparity, generate(0, curved).disparity)
    assert VALIDATION_CONFIG.curved_surfaces == 0
    with pytest.raises(ValueError, match="curved surfaces"):
        SyntheticConfig(curved_surfaces=1.5)
    with pytest.raises(ValueError, match="shapes"):
        random_scene(np.random.default_rng(0), height=64, width=64, max_disparity=8, photo_probability=0,
                     curved_surfaces=0.5)


@pytest.mark.torch  # the train extra: scikit-image's photos paint the scenes
def test_the_photo_share_decides_how_many_surfaces_show_a_photo():
    photos = {id(photo) for photo in load_photos()}
    def photo_share(share: float) -> float:
        layers = [layer for seed in range(12) for layer in random_scene(
            np.random.default_rng(seed), height=128, width=256, max_disparity=48, photo_probability=share)]
        return float(np.mean([id(layer.texture.image) in photos for layer in layers]))
    assert photo_share(0.0) == 0.0 and photo_share(1.0) == 1.0
    assert 0.2 < photo_share(PHOTO_SHARE) < 0.5 < photo_share(0.7) < 0.85
    assert VALIDATION_CONFIG.photo_probability == PHOTO_SHARE
    with pytest.raises(ValueError, match="photo textures"):
        SyntheticConfig(photo_probability=1.2)


def test_a_minified_texture_shows_the_block_means_at_twice_the_frequency():
    image = np.random.default_rng(0).random((8, 10, 3), dtype=np.float32)
    texture = ImageTexture(image, origin=(2.0, -1.0), tint=(1.0, 0.5, 1.0))
    small = minified(texture)
    assert small.image.shape == (4, 5, 3) and small.image.dtype == np.float32
    assert (small.origin, small.scale, small.tint) == (texture.origin, texture.scale, texture.tint)
    # Surface point origin + (i, j) now shows the mean of the 2 x 2 block that origin + (2i, 2j) began.
    x, y = np.array([2.0, 3.0, 6.0]), np.array([-1.0, 0.0, 2.0])
    blocks = image.reshape(4, 2, 5, 2, 3).mean(axis=(1, 3)) * np.float32([1.0, 0.5, 1.0])
    np.testing.assert_allclose(small.sample(x, y), blocks[[0, 1, 3], [0, 1, 4]], rtol=1e-6)
    odd = minified(ImageTexture(image[:7, :9]))
    np.testing.assert_array_equal(odd.image, image[:6, :8].reshape(3, 2, 4, 2, 3).mean(axis=(1, 3)))


@pytest.mark.torch  # the train extra: scikit-image's photos paint the scenes
def test_fine_textures_repaint_that_share_of_the_surfaces_and_leave_the_rest_alone():
    def scene(fine: float) -> list[Layer]:
        return random_scene(np.random.default_rng(5), height=96, width=192, max_disparity=48,
                            photo_probability=0.35, fine_textures=fine,
                            detail=np.random.default_rng([5, 2]) if fine else None)

    plain, some, every = scene(0.0), scene(0.5), scene(1.0)
    # The geometry is the same scene's; only textures change, and with the share at 1 every one does.
    for layers in (some, every):
        assert [layer.surface for layer in layers] == [layer.surface for layer in plain]
        assert [repr(layer.outline) for layer in layers] == [repr(layer.outline) for layer in plain]

    def repainted(layers: list[Layer]) -> list[bool]:
        pairs = zip(plain, layers, strict=True)
        return [not np.array_equal(a.texture.image, b.texture.image) for a, b in pairs]

    assert any(repainted(some)) and not all(repainted(some)) and all(repainted(every))
    # Twice the frequency: the repainted surfaces' paint changes about twice as fast along a row.
    config = SyntheticConfig(height=96, width=192, max_disparity=48, photometric=None)
    fine = SyntheticConfig(height=96, width=192, max_disparity=48, photometric=None, fine_textures=1.0)
    def roughness(sample) -> float:
        grey = sample.left.mean(axis=2)
        return float(np.median(np.abs(np.diff(grey, axis=1))))
    plain_roughness = np.mean([roughness(generate(seed, config)) for seed in range(6)])
    fine_roughness = np.mean([roughness(generate(seed, fine)) for seed in range(6)])
    assert fine_roughness > 1.4 * plain_roughness
    np.testing.assert_array_equal(generate(2, config).disparity, generate(2, fine).disparity)
    assert VALIDATION_CONFIG.fine_textures == 0
    with pytest.raises(ValueError, match="fine textures"):
        SyntheticConfig(fine_textures=-0.5)
    with pytest.raises(ValueError, match="detail"):
        random_scene(np.random.default_rng(0), height=64, width=64, max_disparity=8, photo_probability=0,
                     fine_textures=0.5)


def test_downsampled_averages_blocks_and_keeps_the_truth_only_where_the_block_agrees():
    left = np.arange(4 * 6 * 3, dtype=np.uint8).reshape(4, 6, 3)
    truth = np.array([[4, 4, 8, 8, 6, 6],
                      [4, 4, 8, 8, 6, 7.5],
                      [2, 3, 8, 8, np.nan, 6],
                      [2, 3, 8, 2, 6, 6]], dtype=np.float32)
    visible = np.ones((4, 6), bool)
    visible[3, 0] = False
    sample = StereoSample(name="s", left=left, right=left[:, ::-1].copy(), disparity=truth,
                          nonoccluded=visible, max_disparity=16)
    small = downsampled(sample, 2)
    assert small.left.shape == (2, 3, 3) and small.max_disparity == 8
    np.testing.assert_array_equal(small.left, np.rint(left.reshape(2, 2, 3, 2, 3).mean(axis=(1, 3))))
    # Halved where the four agree to within a rendered pixel; unknown across an edge or a hole.
    np.testing.assert_array_equal(small.disparity, np.array([[2, 4, np.nan], [1.25, np.nan, np.nan]],
                                                            dtype=np.float32))
    np.testing.assert_array_equal(small.nonoccluded, [[True, True, True], [False, True, True]])


@pytest.mark.torch  # the train extra: scikit-image's photos paint the scenes
def test_downsampling_photographs_the_scene_at_that_factor_and_averages_it():
    config = SyntheticConfig(height=48, width=96, max_disparity=24, downsampling=2)
    assert config.rendered == SyntheticConfig(height=96, width=192, max_disparity=48)
    rendering, _ = render_scene(4, config)
    assert rendering.left.shape == (96, 192, 3)
    sample = generate(4, config)
    assert sample.left.shape == (48, 96, 3) and sample.max_disparity == 24
    known = np.isfinite(sample.disparity)
    assert 0.8 < known.mean() < 1 and np.nanmax(sample.disparity) <= 24
    # Without camera effects: the full-size pair's 8-bit renders and truth, averaged.
    exact = generate(4, SyntheticConfig(height=48, width=96, max_disparity=24, downsampling=2,
                                        photometric=None))
    full = generate(4, SyntheticConfig(height=96, width=192, max_disparity=48, photometric=None))
    np.testing.assert_array_equal(exact.left, downsampled(full, 2).left)
    np.testing.assert_array_equal(exact.disparity, sample.disparity)
    # A visible pixel whose truth is a whole disparity finds its own colour in the right view.
    y, x = np.nonzero(known & exact.nonoccluded & (np.abs(exact.disparity - np.rint(exact.disparity)) < 0.05))
    xr = (x - np.rint(exact.disparity[y, x])).astype(int)
    assert np.median(np.abs(exact.left[y, x].astype(int) - exact.right[y, xr].astype(int))) <= 2
    assert VALIDATION_CONFIG.downsampling == 1 and VALIDATION_CONFIG.rendered is VALIDATION_CONFIG
    for bad in (0, 1.5, True):
        with pytest.raises(ValueError, match="downsampling"):
            SyntheticConfig(downsampling=bad)


def test_renderer_refuses_an_uncovered_scene_and_edge_on_planes():
    with pytest.raises(ValueError, match="empty"):
        render([Layer(Plane(0, 0, 3), square(0, 0, 4, 4), SurfaceCoordinates())], height=8, width=8)
    with pytest.raises(ValueError, match="below 1"):
        Plane(1.0, 0, 0)


@pytest.mark.torch
def test_same_seed_same_pair_and_seeds_differ():
    config = SyntheticConfig(height=64, width=128, max_disparity=32)
    first, again, other = generate(7, config), generate(7, config), generate(8, config)
    for field in ("left", "right", "disparity", "nonoccluded"):
        np.testing.assert_array_equal(getattr(first, field), getattr(again, field))
    assert not np.array_equal(first.left, other.left)


@pytest.mark.torch
@pytest.mark.parametrize("seed", [0, 1, 2, 3])
def test_generated_pairs_are_complete_and_in_range(seed):
    config = SyntheticConfig(height=96, width=192, max_disparity=48)
    pair = generate(seed, config)
    assert pair.left.shape == pair.right.shape == (96, 192, 3) and pair.left.dtype == np.uint8
    assert np.isfinite(pair.disparity).all()
    assert pair.disparity.min() >= 0 and pair.disparity.max() <= 48 + 1e-3
    assert pair.nonoccluded.dtype == np.bool_ and 0.5 < pair.nonoccluded.mean() < 1
    assert pair.max_disparity == 48
    # Both views carry texture: no flat image.
    assert pair.left.std() > 5 and pair.right.std() > 5


@pytest.mark.torch
def test_kitti_sized_pairs_reach_large_disparities():
    config = SyntheticConfig(height=375, width=1242, max_disparity=192)
    largest = max(float(generate(seed, config).disparity.max()) for seed in (11, 12))
    assert 150 < largest <= 192 + 1e-3


@pytest.mark.torch
def test_validation_split_is_fixed_seeds_of_a_fixed_config():
    split = validation_split(3)
    assert len(split) == 3 and [split[i].name for i in range(3)] == [
        f"synthetic-{VALIDATION_SEED + i}" for i in range(3)]
    np.testing.assert_array_equal(split[1].left, generate(VALIDATION_SEED + 1, VALIDATION_CONFIG).left)
    assert split[0].left.shape == (VALIDATION_CONFIG.height, VALIDATION_CONFIG.width, 3)
    with pytest.raises(IndexError):
        split[3]


@pytest.mark.torch
def test_photos_are_bundled_natural_images_and_never_a_stereo_pair():
    photos = load_photos()
    assert len(photos) == len(PHOTOS) >= 10
    assert not any("motorcycle" in name for name in PHOTOS)
    assert all(p.dtype == np.float32 and p.ndim == 3 and p.shape[2] == 3 and p.max() <= 1 for p in photos)


def test_image_texture_samples_pixels_and_mirrors_beyond_the_border():
    image = np.random.default_rng(0).random((4, 5, 3)).astype(np.float32)
    texture = ImageTexture(image)
    np.testing.assert_allclose(texture.sample(np.array([2.0]), np.array([1.0])), image[1:2, 2], atol=1e-6)
    np.testing.assert_allclose(texture.sample(np.array([-1.0, 5.0]), np.array([0.0, 0.0])),
                               image[0, [1, 3]], atol=1e-6)
    np.testing.assert_allclose(texture.sample(np.array([0.5]), np.array([0.0])),
                               (image[0:1, 0] + image[0:1, 1]) / 2, atol=1e-6)


def test_camera_effects_differ_per_view_and_are_reproducible():
    image = np.random.default_rng(1).random((32, 48, 3)).astype(np.float32)
    effects = Photometric(blur_probability=1.0, jpeg_probability=1.0)
    first = apply_camera(image, np.random.default_rng(5), effects)
    again = apply_camera(image, np.random.default_rng(5), effects)
    other = apply_camera(image, np.random.default_rng(6), effects)
    np.testing.assert_array_equal(first, again)
    assert first.dtype == np.uint8 and first.shape == (32, 48, 3)
    assert np.abs(first.astype(int) - other.astype(int)).mean() > 1
    exact = apply_camera(image, np.random.default_rng(5), None)
    np.testing.assert_array_equal(exact, (image * 255 + 0.5).astype(np.uint8))


@pytest.mark.torch  # the train extra: the generator paints with scikit-image's photographs
def test_camera_geometry_and_vignetting_levers_are_off_by_default_and_do_what_they_say() -> None:
    """Training-only levers (issue 11's data levers): off, they draw nothing, so the fixed validation split
    keeps its pixels; on, vignetting darkens the corners and the rectification error moves rows only."""
    import dataclasses

    from training.data.synthetic import Rectification
    from training.data.synthetic.photometric import rectify_imperfectly

    config = SyntheticConfig(height=48, width=80, max_disparity=16)
    plain = generate(11, config)
    explicit = generate(11, dataclasses.replace(config, photometric=Photometric(vignetting=(0.0, 0.0))))
    assert np.array_equal(plain.left, explicit.left) and np.array_equal(plain.right, explicit.right)

    flat = SyntheticConfig(height=48, width=80, max_disparity=16,
                           photometric=Photometric(gain=(1.0, 1.0), channel_gain=0.0, bias=(0.0, 0.0),
                                                   gamma=(1.0, 1.0), noise_sigma=(0.0, 0.0),
                                                   blur_probability=0.0, jpeg_probability=0.0))
    dark = generate(11, dataclasses.replace(flat, photometric=dataclasses.replace(flat.photometric,
                                                                                    vignetting=(0.3, 0.3))))
    clean = generate(11, flat)
    ratio = dark.left.astype(float).sum(-1) / np.maximum(clean.left.astype(float).sum(-1), 1)
    assert ratio[20:28, 36:44].mean() > 0.98 and ratio[:4, :4].mean() < 0.75   # centre kept, corners darker

    misaligned = generate(11, dataclasses.replace(flat, rectification=Rectification()))
    assert np.array_equal(misaligned.left, clean.left)
    assert np.array_equal(misaligned.disparity, clean.disparity)
    assert not np.array_equal(misaligned.right, clean.right)
    # Only rows move: an image that varies along x only is unchanged; one that varies along y shifts by
    # at most the drawn shift plus the rotation's and scale's vertical parts (~1.2 px at 48 x 80).
    columns = np.tile(np.linspace(0, 1, 80, dtype=np.float32)[None, :, None], (48, 1, 3))
    unchanged = rectify_imperfectly(columns, np.random.default_rng(0), Rectification())
    np.testing.assert_allclose(unchanged, columns, atol=1e-6)
    rows = np.tile(np.arange(48, dtype=np.float32)[:, None, None], (1, 80, 3))
    moved = rectify_imperfectly(rows, np.random.default_rng(0), Rectification())[4:-4] - rows[4:-4]
    assert 0.0 < np.abs(moved).max() <= 1.0 + 0.2 * np.pi / 180 * 40 + 0.003 * 24 + 1e-4
