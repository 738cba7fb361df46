"""Synthetic stereo pairs with exact ground truth: random layered scenes, rendered, then photographed.

A scene (see ``scene.py``) holds 1-3 slanted background planes, often a ground plane, objects (ellipses,
rectangles, star polygons) at nearer, slightly slanted depths, and thin structures (poles, wires, fences).
Every surface gets a procedural or photo texture (``textures.py``), each view its own camera effects
(``photometric.py``). Everything is drawn from ``numpy.random.default_rng(seed)``: a seed is a pair.

Seeds from ``VALIDATION_SEED`` on are the fixed validation split (``validation_split``); training must
draw its seeds below it.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import numpy as np

from service.datasets import StereoSample
from training.data.photos import data_folder

from .photometric import Photometric, Rectification, apply_camera, rectify_imperfectly
from .scene import (
    DOME_MAX_SLOPE,
    Below,
    Dome,
    Ellipse,
    Everywhere,
    Layer,
    Plane,
    Polygon,
    Rendering,
    Segment,
    Shaded,
    render,
)
from .textures import ImageTexture, blocks, minified, random_texture

VALIDATION_SEED = 1_000_000_000
DEFAULT_VALIDATION_COUNT = 20           # what the SPEC ``synthetic`` without ``:N`` means
DIAGNOSTIC_SHARE = 0.5                  # the lever's share in the SPECs synthetic-curved and synthetic-fine
DOWNSAMPLING = 2                        # the factor of the SPEC synthetic-downsampled and --downsampled-views
PHOTO_SHARE = 0.35                      # share of surfaces painted with a photo (the split's)


@dataclasses.dataclass(frozen=True, kw_only=True)
class SyntheticConfig:
    height: int = 256
    width: int = 512
    max_disparity: int = 128            # the nearest surface of a scene is at most this far
    photo_probability: float = PHOTO_SHARE  # share of surfaces painted with a photo
    photometric: Photometric | None = dataclasses.field(default_factory=Photometric)
    rectification: Rectification | None = None   # residual rectification error of the right view (training)
    curved_surfaces: float = 0.0        # training: share of objects that bulge towards the cameras, shaded
    fine_textures: float = 0.0          # training: share of surfaces painted at twice the spatial frequency
    # Render and photograph at this many times the size and range, then average blocks of that side: a
    # downsampled photograph, as Middlebury's quarter-size pairs are (finer scenes, anti-aliased edges,
    # camera noise divided by the factor). 1: the pixels as rendered.
    downsampling: int = 1

    def __post_init__(self) -> None:
        if self.height < 8 or self.width < 8:
            raise ValueError(f"synthetic images must be at least 8 x 8, got {self.height} x {self.width}")
        if self.max_disparity < 1:
            raise ValueError(f"max_disparity must be positive, got {self.max_disparity}")
        check_share("photo textures", self.photo_probability)
        check_share("curved surfaces", self.curved_surfaces)
        check_share("fine textures", self.fine_textures)
        if isinstance(self.downsampling, bool) or not isinstance(self.downsampling, int) \
                or self.downsampling < 1:
            raise ValueError(f"downsampling must be a whole number >= 1, got {self.downsampling!r}")

    @property
    def rendered(self) -> SyntheticConfig:
        """The config the scene is drawn, rendered and photographed at (itself without downsampling)."""
        factor = self.downsampling
        if factor == 1:
            return self
        return dataclasses.replace(self, height=self.height * factor, width=self.width * factor,
                                   max_disparity=self.max_disparity * factor, downsampling=1)


def check_share(what: str, share: float) -> None:
    """ValueError unless ``share`` is in [0, 1] (NaN is not): the check of every share-valued lever."""
    if not 0.0 <= share <= 1.0:
        raise ValueError(f"{what} must be a share in [0, 1], got {share}")


# The validation split: fixed seeds, size and range (documented in docs/data.md; never change them).
VALIDATION_CONFIG = SyntheticConfig(height=256, width=512, max_disparity=128)


def generate(seed: int, config: SyntheticConfig = SyntheticConfig()) -> StereoSample:
    """The synthetic pair of ``seed``: same seed and config, same pixels."""
    rendering, camera = render_scene(seed, config)
    return photograph(rendering, camera, config, name=f"synthetic-{seed}")


def render_scene(seed: int, config: SyntheticConfig = SyntheticConfig()
                 ) -> tuple[Rendering, np.random.Generator]:
    """The exact two-view rendering of ``seed``'s scene, and the seed's stream where the scene's draws end:
    ``photograph`` with that stream gives ``generate(seed, config)``; with another, the same scene taken by
    other cameras (most of a pair's cost is the scene and its rendering, not the cameras)."""
    config = config.rendered
    rng = np.random.default_rng(seed)
    # The curved surfaces and the fine textures draw from streams of their own, so that a scene keeps
    # every other layer, texture and camera with a lever on (and draws nothing more with it off).
    shapes = np.random.default_rng([seed, 1]) if config.curved_surfaces else None
    detail = np.random.default_rng([seed, 2]) if config.fine_textures else None
    layers = random_scene(rng, height=config.height, width=config.width,
                          max_disparity=config.max_disparity, photo_probability=config.photo_probability,
                          curved_surfaces=config.curved_surfaces, shapes=shapes,
                          fine_textures=config.fine_textures, detail=detail)
    return render(layers, height=config.height, width=config.width), rng


def other_cameras(seed: int, draw: int) -> np.random.Generator:
    """The stream of the ``draw``-th other cameras (``draw`` >= 1) that photograph ``seed``'s scene; its
    own cameras continue ``render_scene``'s stream, and [seed, 1] and [seed, 2] are the levers'."""
    return np.random.default_rng([seed, 3, draw])


def photograph(rendering: Rendering, camera: np.random.Generator, config: SyntheticConfig, *,
               name: str) -> StereoSample:
    """Both views of ``rendering`` through the cameras of ``config`` (effects drawn from ``camera``);
    with ``config.downsampling`` > 1, photographed at the rendering's size, then ``downsampled``."""
    left = apply_camera(rendering.left, camera, config.photometric)
    right = rendering.right
    if config.rectification is not None:
        right = rectify_imperfectly(right, camera, config.rectification)
    right = apply_camera(right, camera, config.photometric)
    sample = StereoSample(name=name, left=left, right=right, disparity=rendering.disparity,
                          nonoccluded=~rendering.occluded, max_disparity=config.rendered.max_disparity)
    return sample if config.downsampling == 1 else downsampled(sample, config.downsampling)


# A downsampled pixel keeps a ground truth only where the rendered pixels it averages agree to within this
# many rendered pixels of disparity: across a depth edge the block mixes two surfaces, and no one disparity
# is its truth.
DOWNSAMPLED_TRUTH_SPREAD = 1.0


def downsampled(sample: StereoSample, factor: int) -> StereoSample:
    """``sample`` averaged over ``factor`` x ``factor`` blocks: views rounded to 8 bits, the disparity the
    block's mean over ``factor`` (unknown where the block spans more than ``DOWNSAMPLED_TRUTH_SPREAD``),
    visible where the whole block is, the range divided by ``factor``."""
    def view(image: np.ndarray) -> np.ndarray:
        return np.rint(blocks(image, factor).mean(axis=(1, 3), dtype=np.float32)).astype(np.uint8)

    truth = blocks(sample.disparity, factor)
    spread = truth.max(axis=(1, 3)) - truth.min(axis=(1, 3))
    disparity = np.where(spread <= DOWNSAMPLED_TRUTH_SPREAD, truth.mean(axis=(1, 3)) / factor, np.nan)
    nonoccluded = None if sample.nonoccluded is None else blocks(sample.nonoccluded, factor).all(axis=(1, 3))
    max_disparity = None if sample.max_disparity is None else sample.max_disparity // factor
    return StereoSample(name=sample.name, left=view(sample.left), right=view(sample.right),
                        disparity=disparity.astype(np.float32), nonoccluded=nonoccluded,
                        max_disparity=max_disparity)


class SyntheticStereo(Sequence[StereoSample]):
    """``count`` pairs with seeds ``first_seed``, ``first_seed + 1``, ... (generated on access)."""

    def __init__(self, *, count: int, first_seed: int = 0, config: SyntheticConfig = SyntheticConfig()):
        if count < 1:
            raise ValueError(f"count must be positive, got {count}")
        self.count, self.first_seed, self.config = count, first_seed, config
        self.name = f"synthetic seeds {first_seed}..{first_seed + count - 1}"

    def __len__(self) -> int:
        return self.count

    def __getitem__(self, index):  # type: ignore[override]
        if isinstance(index, slice):
            return [self[i] for i in range(*index.indices(self.count))]
        if not -self.count <= index < self.count:
            raise IndexError(f"pair {index} out of range (0..{self.count - 1})")
        return generate(self.first_seed + index % self.count, self.config)


def validation_split(count: int = DEFAULT_VALIDATION_COUNT, *, camera_effects: bool = True,
                     curved_surfaces: float = 0.0, fine_textures: float = 0.0,
                     downsampling: int = 1) -> SyntheticStereo:
    """The first ``count`` pairs of the fixed synthetic validation split. The other arguments make
    diagnostics of the same seeds (docs/data.md): ``camera_effects=False`` renders them exactly (8-bit
    only), telling the scenes' difficulty from the cameras'; ``curved_surfaces`` and ``fine_textures``
    apply the training levers of those names, so a matcher can be measured on what they add;
    ``downsampling`` photographs them at that factor and averages blocks (other scenes: a larger image
    draws more objects)."""
    config = dataclasses.replace(VALIDATION_CONFIG, curved_surfaces=curved_surfaces,
                                 fine_textures=fine_textures, downsampling=downsampling)
    if not camera_effects:
        config = dataclasses.replace(config, photometric=None)
    variants = [" without camera effects"] if not camera_effects else []
    variants += [f" with {lever} (share {share:g})" for lever, share in
                 (("curved surfaces", curved_surfaces), ("fine textures", fine_textures)) if share]
    variants += [f" photographed at {downsampling}x and averaged"] if downsampling > 1 else []
    split = SyntheticStereo(count=count, first_seed=VALIDATION_SEED, config=config)
    split.name = f"synthetic validation{','.join(variants)} ({count} pairs)"
    return split


def open_validation_split(argument: str) -> SyntheticStereo:
    """The dataset SPEC ``synthetic[:N]`` (``argument`` is N or ''), registered for ``service.datasets``.

    Raises ModuleNotFoundError now, before any pair is drawn, when scikit-image's photos are missing, so
    that ``adsm eval`` can name the extra to install.
    """
    return validation_split(_pair_count(argument))


def open_clean_validation_split(argument: str) -> SyntheticStereo:
    """The dataset SPEC ``synthetic-clean[:N]``: the split's first N scenes without camera effects."""
    return validation_split(_pair_count(argument), camera_effects=False)


def open_curved_validation_split(argument: str) -> SyntheticStereo:
    """The dataset SPEC ``synthetic-curved[:N]``: the split's first N scenes, cameras included, with the
    ``curved_surfaces`` lever at ``DIAGNOSTIC_SHARE``."""
    return validation_split(_pair_count(argument), curved_surfaces=DIAGNOSTIC_SHARE)


def open_fine_validation_split(argument: str) -> SyntheticStereo:
    """The dataset SPEC ``synthetic-fine[:N]``: the split's first N scenes, cameras included, with the
    ``fine_textures`` lever at ``DIAGNOSTIC_SHARE``."""
    return validation_split(_pair_count(argument), fine_textures=DIAGNOSTIC_SHARE)


def open_downsampled_validation_split(argument: str) -> SyntheticStereo:
    """The dataset SPEC ``synthetic-downsampled[:N]``: the split's first N seeds, cameras included,
    photographed at twice the size and averaged 2 x 2 (``SyntheticConfig.downsampling``)."""
    return validation_split(_pair_count(argument), downsampling=DOWNSAMPLING)


def _pair_count(argument: str) -> int:
    if argument and (not argument.isdigit() or int(argument) < 1):
        raise ValueError(f"N must be a positive pair count, got {argument!r}")
    data_folder()
    return int(argument) if argument else DEFAULT_VALIDATION_COUNT


def random_scene(rng: np.random.Generator, *, height: int, width: int, max_disparity: int,
                 photo_probability: float, curved_surfaces: float = 0.0,
                 shapes: np.random.Generator | None = None, fine_textures: float = 0.0,
                 detail: np.random.Generator | None = None) -> list[Layer]:
    """Layers of a random scene; disparities stay within [0, max_disparity]. With ``curved_surfaces`` > 0,
    that share of the objects bulge towards the cameras (``Dome``, shaded), drawn from ``shapes``; with
    ``fine_textures`` > 0, that share of the surfaces is painted at twice the spatial frequency (the texture
    drawn from ``detail`` over twice the region, then ``minified``)."""
    if curved_surfaces and shapes is None:
        raise ValueError("curved surfaces draw from a generator of their own: pass shapes")
    if fine_textures and detail is None:
        raise ValueError("fine textures draw from a generator of their own: pass detail")
    builder = _SceneBuilder(rng, height, width, float(max_disparity), photo_probability, curved_surfaces,
                            shapes, fine_textures, detail)
    far = rng.uniform(0, 0.2) * max_disparity
    for _ in range(1 + (rng.random() < 0.4) + (rng.random() < 0.15)):
        builder.background(far + rng.uniform(0, 0.1) * max_disparity)
    if rng.random() < 0.6:
        builder.ground(far)
    scale = height * width / (256 * 512)
    for _ in range(int(rng.integers(3, 6 + int(16 * np.sqrt(scale))))):
        builder.solid()
    for _ in range(int(rng.choice(4, p=(0.35, 0.35, 0.2, 0.1)))):
        builder.thin()
    if rng.random() < 0.15:
        builder.fence()
    return builder.layers


class _SceneBuilder:
    """Draws layer parameters; keeps each plane's disparity inside [0, max_disparity] where it is seen."""

    def __init__(self, rng: np.random.Generator, height: int, width: int, max_disparity: float,
                 photo_probability: float, curved_surfaces: float = 0.0,
                 shapes: np.random.Generator | None = None, fine_textures: float = 0.0,
                 detail: np.random.Generator | None = None):
        self.rng, self.height, self.width, self.dmax = rng, height, width, max_disparity
        self.photo_probability = photo_probability
        self.curved_surfaces, self.shapes = curved_surfaces, shapes
        self.fine_textures, self.detail = fine_textures, detail
        self.layers: list[Layer] = []

    def background(self, disparity: float) -> None:
        rng, reach = self.rng, self.width + self.dmax
        a = rng.uniform(-0.15, 0.15) * self.dmax / reach
        b = rng.uniform(-0.15, 0.15) * self.dmax / self.height
        box = (0, 0, reach, self.height)
        self._add(self._fit(a, b, disparity, box), Everywhere(), box)

    def ground(self, far: float) -> None:
        rng, height, reach = self.rng, self.height, self.width + self.dmax
        horizon = rng.uniform(0.25, 0.7) * height
        near = rng.uniform(0.3, 1.0) * self.dmax
        b = (near - far) / (height - horizon)
        a = rng.uniform(-0.05, 0.05) * (near - far) / reach
        plane = self._fit(a, b, far + b * (height - 1 - horizon) / 2, (0, horizon, reach, height))
        self._add(plane, Below(horizon), (0, horizon, reach, height))

    def solid(self) -> None:
        rng, size = self.rng, min(self.height, self.width)
        disparity = rng.uniform(0.15, 1.0) * self.dmax
        radius = float(np.exp(rng.uniform(np.log(0.05), np.log(0.5)))) * size
        cx, cy = rng.uniform(-0.1 * self.width, self.width + 0.5 * disparity), rng.uniform(0, self.height)
        kind = rng.choice(3, p=(0.35, 0.4, 0.25))
        if kind == 0:
            outline = Ellipse(cx, cy, radius, radius * rng.uniform(0.3, 1.0), rng.uniform(0, np.pi))
        else:
            count = int(rng.integers(5, 11)) if kind == 1 else 4
            angles = np.sort(rng.uniform(0, 2 * np.pi, count)) if kind == 1 else \
                rng.uniform(0, np.pi / 2) + np.array([0.0, 1.0, 2.0, 3.0]) * np.pi / 2
            radii = radius * (rng.uniform(0.35, 1.0, count) if kind == 1 else np.ones(count))
            if kind == 2:  # a rectangle: stretch a rotated square along one axis
                angles = angles + rng.uniform(-0.3, 0.3) * np.array([1, -1, 1, -1])
            outline = Polygon(np.stack([cx + radii * np.cos(angles), cy + radii * np.sin(angles)], axis=1))
        box = (cx - radius, cy - radius, cx + radius, cy + radius)
        a, b = rng.uniform(-0.25, 0.25, 2) * min(1.0, disparity / max(radius, 1.0))
        plane = self._fit(a, b, disparity, box)
        texture = self._texture(box)
        if self.shapes is not None and self.shapes.random() < self.curved_surfaces:
            ellipse = outline if isinstance(outline, Ellipse) else Ellipse(cx, cy, radius, radius)
            dome, texture = self._bulge(plane, ellipse, box, texture)
            self.layers.append(Layer(dome, outline, texture))
        else:
            self.layers.append(Layer(plane, outline, texture))

    def thin(self) -> None:
        rng = self.rng
        disparity = rng.uniform(0.2, 1.0) * self.dmax
        length = rng.uniform(0.2, 1.2) * self.height
        angle = np.pi / 2 + (rng.uniform(-0.3, 0.3) if rng.random() < 0.7 else rng.uniform(-1.5, 1.5))
        x0, y0 = rng.uniform(0, self.width + 0.5 * disparity), rng.uniform(-0.2, 1.0) * self.height
        x1, y1 = x0 + length * np.cos(angle), y0 + length * np.sin(angle)
        half_width = rng.uniform(0.6, 2.5)
        box = (min(x0, x1) - 3, min(y0, y1) - 3, max(x0, x1) + 3, max(y0, y1) + 3)
        b = rng.uniform(-0.1, 0.1) * disparity / max(length, 1.0)
        self._add(self._fit(0.0, b, disparity, box), Segment(x0, y0, x1, y1, half_width), box)

    def fence(self) -> None:
        """Evenly spaced bars on one plane: a repetitive pattern that plain matching confuses."""
        rng = self.rng
        disparity = rng.uniform(0.3, 1.0) * self.dmax
        count, spacing = int(rng.integers(4, 13)), rng.uniform(6, 25)
        half_width = rng.uniform(0.8, 3.0)
        x0, top = rng.uniform(0, self.width), rng.uniform(0, 0.5) * self.height
        bottom = top + rng.uniform(0.3, 0.8) * self.height
        box = (x0 - 4, top - 4, x0 + count * spacing + 4, bottom + 4)
        plane = self._fit(0.0, 0.0, disparity, box)
        texture = self._texture(box)
        for i in range(count):
            x = x0 + i * spacing
            self.layers.append(Layer(plane, Segment(x, top, x, bottom, half_width), texture))

    def _bulge(self, plane: Plane, ellipse: Ellipse, box: tuple[float, float, float, float],
               texture: ImageTexture) -> tuple[Dome, Shaded]:
        """The object as a solid ``relief`` times its radius high: a sphere of image radius r at disparity d
        seen with a focal length of f pixels comes nearer by about d r / f at its centre. The bulge is cut
        to stay inside [0, max_disparity] and below ``DOME_MAX_SLOPE``."""
        shapes = self.shapes
        assert shapes is not None
        relief = shapes.uniform(0.3, 1.0)
        focal = shapes.uniform(0.5, 1.5) * self.width
        radius = (ellipse.rx + ellipse.ry) / 2
        height = plane.at(np.float64(ellipse.cx), np.float64(ellipse.cy)) * relief * radius / focal
        x0, y0, x1, y1 = box
        highest = max(plane.at(np.float64(x), np.float64(y)) for x in (x0, x1) for y in (y0, y1))
        steepest = (DOME_MAX_SLOPE - abs(plane.a)) * min(ellipse.rx, ellipse.ry) / 2
        height = float(np.clip(min(height, self.dmax - highest, 0.999 * steepest), 0.0, None))
        dome = Dome(plane, ellipse.cx, ellipse.cy, ellipse.rx, ellipse.ry, ellipse.angle, height)
        azimuth, elevation = shapes.uniform(0, 2 * np.pi), shapes.uniform(np.pi / 6, 5 * np.pi / 12)
        light = (float(np.cos(elevation) * np.cos(azimuth)), float(np.cos(elevation) * np.sin(azimuth)),
                 float(np.sin(elevation)))
        return dome, Shaded(texture, dome, relief, light, ambient=float(shapes.uniform(0.2, 0.6)))

    def _fit(self, a: float, b: float, disparity: float, box: tuple[float, float, float, float]) -> Plane:
        """Plane with slopes a, b whose mean over ``box`` is ``disparity``, slopes shrunk to stay in range."""
        x0, y0, x1, y1 = box
        cx, cy = (x0 + x1) / 2, (y0 + y1) / 2
        spread = abs(a) * (x1 - x0) / 2 + abs(b) * (y1 - y0) / 2
        room = min(disparity, self.dmax - disparity)
        if spread > room:
            shrink = room / spread
            a, b = a * shrink, b * shrink
        return Plane(a, b, disparity - a * cx - b * cy)

    def _texture(self, box: tuple[float, float, float, float]) -> ImageTexture:
        x0, y0, x1, y1 = (float(v) for v in box)
        height, width = int(np.ceil(y1 - y0)) + 1, int(np.ceil(x1 - x0)) + 1
        texture = random_texture(self.rng, height=height, width=width, origin=(x0, y0),
                                 photo_probability=self.photo_probability)
        # The scene's own texture is drawn either way, so the rest of the scene stays that of a run without
        # the lever; a fine one replaces it.
        if self.detail is not None and self.detail.random() < self.fine_textures:
            texture = minified(random_texture(self.detail, height=2 * height, width=2 * width,
                                              origin=(x0, y0), photo_probability=self.photo_probability))
        return texture

    def _add(self, plane: Plane, outline, box: tuple[float, float, float, float]) -> None:
        self.layers.append(Layer(plane, outline, self._texture(box)))
