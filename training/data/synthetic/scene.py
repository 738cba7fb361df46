"""Layered scenes in disparity space and their exact two-view rendering.

A scene is a stack of layers. Each layer is a surface in disparity space, usually a plane
``d = a x + b y + c`` in left-image pixels (a 3-D plane seen by a rectified pair is exactly such a plane),
sometimes a plane with a smooth bulge towards the cameras (``Dome``, a training-only lever); an outline in
the left image that says where the surface exists; and a texture painted on the surface (texture
coordinates are the surface point's left-image coordinates, so both views see the same paint).

Both views are ray-cast, never warped: a right pixel ``x_r`` meets layer k at the left abscissa ``x`` that
solves ``x_r = x - d(x, y)`` (``(x_r + b y + c) / (1 - a)`` for a plane), which is inside the layer or not.
A z-buffer keeps the largest disparity (the nearest surface). So the right view has no holes and no
resampling cracks, occlusions are exact, and the disparity ground truth is the float value of the visible
surface.
"""

from __future__ import annotations

import dataclasses
from typing import Protocol

import numpy as np

# A left pixel is occluded when the right view sees a surface this much nearer at its match.
_OCCLUSION_TOLERANCE = 1e-3


@dataclasses.dataclass(frozen=True)
class Plane:
    """Disparity plane ``d(x, y) = a x + b y + c`` (left-image pixels)."""

    a: float
    b: float
    c: float

    def __post_init__(self) -> None:
        # a >= 1 would put the surface edge-on or behind the right camera: x_r would not grow with x.
        if not self.a < 1.0:
            raise ValueError(f"plane slope a = {self.a} must be below 1 (surface seen edge-on)")

    def at(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        return self.a * x + self.b * y + self.c

    def left_x(self, x_right: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Left abscissa of the plane point that the right view sees at ``x_right``."""
        return (x_right + self.b * y + self.c) / (1.0 - self.a)


class Surface(Protocol):
    """A layer's disparity ``d(x, y)`` in left-image pixels, seen by both views."""

    def at(self, x: np.ndarray, y: np.ndarray) -> np.ndarray: ...

    def left_x(self, x_right: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Left abscissa of the surface point that the right view sees at ``x_right``."""
        ...


# A dome's disparity may change by at most this much per pixel along a row (|dd/dx|): the fixed point of
# its ray casting then contracts by half an iteration, and the right view never sees it edge-on.
DOME_MAX_SLOPE = 0.5
_DOME_ITERATIONS = 40  # at most: 0.5 ** 40 is far below float32's resolution of any abscissa
_DOME_CONVERGED = 1e-4  # px: the iteration stops once no abscissa moves more


@dataclasses.dataclass(frozen=True)
class Dome:
    """A plane with a paraboloid bulge towards the cameras over an ellipse: the disparity of a gently
    curved object (a ball, a cone's flank, a cushion) seen by a rectified pair,
    ``d = plane(x, y) + height * max(0, 1 - r^2)``, r the ellipse's normalised radius (r = 1 on its rim).

    The right view's ray casting solves ``x = x_r + d(x, y)`` by fixed-point iteration from the plane's
    solution; ``DOME_MAX_SLOPE`` bounds ``|dd/dx|`` so that the iteration contracts.
    """

    plane: Plane
    cx: float
    cy: float
    rx: float
    ry: float
    angle: float
    height: float

    def __post_init__(self) -> None:
        if not (self.rx > 0 and self.ry > 0 and self.height >= 0):
            raise ValueError(f"a dome needs positive radii and a height >= 0, got {self.rx}, {self.ry}, "
                             f"{self.height}")
        if abs(self.plane.a) + self.max_bulge_slope > DOME_MAX_SLOPE:
            raise ValueError(f"dome too steep: |a| + 2 height / min radius = "
                             f"{abs(self.plane.a) + self.max_bulge_slope:.3f} > {DOME_MAX_SLOPE}")

    @property
    def max_bulge_slope(self) -> float:
        """The largest |dd/dx| the bulge adds (on its rim, along its shorter axis)."""
        return 2.0 * self.height / min(self.rx, self.ry)

    def _frame(self, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(u, v): the ellipse's own axes, scaled so that its rim is u^2 + v^2 = 1."""
        cos, sin = np.cos(self.angle), np.sin(self.angle)
        dx, dy = x - self.cx, y - self.cy
        return (cos * dx + sin * dy) / self.rx, (-sin * dx + cos * dy) / self.ry

    def at(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        u, v = self._frame(x, y)
        return self.plane.at(x, y) + self.height * np.maximum(0.0, 1.0 - u * u - v * v)

    def left_x(self, x_right: np.ndarray, y: np.ndarray) -> np.ndarray:
        x = self.plane.left_x(x_right, y)
        for _ in range(_DOME_ITERATIONS):
            x, previous = x_right + self.at(x, y), x
            if np.max(np.abs(x - previous), initial=0.0) < _DOME_CONVERGED:
                break
        return x

    def normal(self, x: np.ndarray, y: np.ndarray, relief: float) -> np.ndarray:
        """Unit normals (..., 3) of the solid whose depth profile is the bulge's, ``relief`` times its mean
        radius high at the centre (x right, y down, z towards the cameras), for shading."""
        u, v = self._frame(x, y)
        inside = (u * u + v * v) <= 1.0
        scale = 2.0 * relief * (self.rx + self.ry) / 2.0
        du, dv = np.where(inside, -scale * u / self.rx, 0.0), np.where(inside, -scale * v / self.ry, 0.0)
        cos, sin = np.cos(self.angle), np.sin(self.angle)
        dz_dx, dz_dy = cos * du - sin * dv, sin * du + cos * dv
        normal = np.stack([-dz_dx, -dz_dy, np.ones_like(dz_dx)], axis=-1)
        return normal / np.linalg.norm(normal, axis=-1, keepdims=True)


@dataclasses.dataclass(frozen=True)
class Shaded:
    """A dome's texture lit by a distant light as a matte (Lambertian) surface reflects it: the brightness
    depends on the surface normal only, not on the viewpoint, so both views still show the same paint.
    Real curved objects are shaded, the generator's planes are not."""

    texture: Texture
    dome: Dome
    relief: float                        # the solid's height over its mean radius (Dome.normal)
    light: tuple[float, float, float]    # unit vector towards the light (z towards the cameras)
    ambient: float                       # brightness where the light does not reach

    def sample(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        lambert = np.clip(self.dome.normal(x, y, self.relief) @ np.asarray(self.light), 0.0, None)
        shade = (self.ambient + (1.0 - self.ambient) * lambert).astype(np.float32)
        return self.texture.sample(x, y) * shade[:, None]


class Outline(Protocol):
    """Where a layer's surface exists, in left-image coordinates."""

    def contains(self, x: np.ndarray, y: np.ndarray) -> np.ndarray: ...

    def rows(self, height: int) -> tuple[int, int]:
        """Half-open range of image rows the outline can touch (rows are shared by both views)."""
        ...


class Texture(Protocol):
    def sample(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """float32 colours (N, 3) in [0, 1] at surface coordinates ``x``, ``y`` (float arrays of N)."""
        ...


@dataclasses.dataclass(frozen=True)
class Everywhere:
    """Unbounded surface: a background plane. Every scene needs one so that no pixel is left empty."""

    def contains(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        return np.ones(np.broadcast_shapes(np.shape(x), np.shape(y)), dtype=bool)

    def rows(self, height: int) -> tuple[int, int]:
        return 0, height


@dataclasses.dataclass(frozen=True)
class Below:
    """The half plane ``y >= horizon``: a ground plane."""

    horizon: float

    def contains(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        return np.broadcast_to(y >= self.horizon, np.broadcast_shapes(np.shape(x), np.shape(y)))

    def rows(self, height: int) -> tuple[int, int]:
        return _clip_rows(self.horizon, height, height)


@dataclasses.dataclass(frozen=True)
class Ellipse:
    cx: float
    cy: float
    rx: float
    ry: float
    angle: float = 0.0

    def contains(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        cos, sin = np.cos(self.angle), np.sin(self.angle)
        dx, dy = x - self.cx, y - self.cy
        u, v = (cos * dx + sin * dy) / self.rx, (-sin * dx + cos * dy) / self.ry
        return u * u + v * v <= 1.0

    def rows(self, height: int) -> tuple[int, int]:
        reach = max(self.rx, self.ry)
        return _clip_rows(self.cy - reach, self.cy + reach + 1, height)


@dataclasses.dataclass(frozen=True)
class Polygon:
    """Simple polygon (vertices in order, as an (N, 2) array of x, y); even-odd rule."""

    vertices: np.ndarray

    def contains(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        inside = np.zeros(np.broadcast_shapes(np.shape(x), np.shape(y)), dtype=bool)
        following = np.roll(self.vertices, -1, axis=0)
        for (x0, y0), (x1, y1) in zip(self.vertices, following, strict=True):
            if y0 == y1:
                continue  # a horizontal edge never crosses a horizontal ray
            straddles = (y0 > y) != (y1 > y)
            crossing = x0 + (y - y0) * (x1 - x0) / (y1 - y0)
            inside ^= straddles & (x < crossing)
        return inside

    def rows(self, height: int) -> tuple[int, int]:
        ys = self.vertices[:, 1]
        return _clip_rows(ys.min(), ys.max() + 1, height)


@dataclasses.dataclass(frozen=True)
class Segment:
    """A thick line segment: poles, wires, fence bars (thin structures)."""

    x0: float
    y0: float
    x1: float
    y1: float
    half_width: float

    def contains(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        ex, ey = self.x1 - self.x0, self.y1 - self.y0
        t = np.clip(((x - self.x0) * ex + (y - self.y0) * ey) / max(ex * ex + ey * ey, 1e-12), 0.0, 1.0)
        dx, dy = x - (self.x0 + t * ex), y - (self.y0 + t * ey)
        return dx * dx + dy * dy <= self.half_width**2

    def rows(self, height: int) -> tuple[int, int]:
        return _clip_rows(min(self.y0, self.y1) - self.half_width,
                          max(self.y0, self.y1) + self.half_width + 1, height)


@dataclasses.dataclass(frozen=True)
class Layer:
    surface: Surface
    outline: Outline
    texture: Texture


@dataclasses.dataclass(frozen=True)
class Rendering:
    left: np.ndarray              # float32 (H, W, 3) in [0, 1]
    right: np.ndarray             # float32 (H, W, 3) in [0, 1]
    disparity: np.ndarray         # float32 (H, W): disparity of the left view
    disparity_right: np.ndarray   # float32 (H, W): disparity of the right view (x_left = x_right + d)
    occluded: np.ndarray          # bool (H, W): left pixel not visible in the right view (or out of frame)


def render(layers: list[Layer], *, height: int, width: int) -> Rendering:
    """Render both views of ``layers`` with exact occlusions (nearest = largest disparity wins)."""
    if height < 1 or width < 1:
        raise ValueError(f"image size must be positive, got {height} x {width}")
    left_disparity, left_owner, left_x = _cast(layers, height, width, right_view=False)
    right_disparity, right_owner, right_x = _cast(layers, height, width, right_view=True)
    rows = np.broadcast_to(np.arange(height, dtype=np.float32)[:, None], (height, width))
    left = _paint(layers, left_owner, left_x, rows)
    right = _paint(layers, right_owner, right_x, rows)
    occluded = _occluded(layers, left_disparity, rows)
    return Rendering(left, right, left_disparity, right_disparity, occluded)


def _cast(layers: list[Layer], height: int, width: int, *, right_view: bool
          ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Z-buffer one view: disparity, index of the visible layer and its left abscissa per pixel."""
    disparity = np.full((height, width), -np.inf, dtype=np.float32)
    owner = np.full((height, width), -1, dtype=np.int16)
    surface_x = np.zeros((height, width), dtype=np.float32)
    columns = np.arange(width, dtype=np.float32)[None, :]
    for index, layer in enumerate(layers):
        top, bottom = layer.outline.rows(height)
        if top >= bottom:
            continue
        y = np.arange(top, bottom, dtype=np.float32)[:, None]
        surface = layer.surface
        x = surface.left_x(columns, y) if right_view else np.broadcast_to(columns, (bottom - top, width))
        d = surface.at(x, y)
        nearer = layer.outline.contains(x, y) & (d > disparity[top:bottom])
        disparity[top:bottom][nearer] = d[nearer]
        owner[top:bottom][nearer] = index
        surface_x[top:bottom][nearer] = x[nearer]
    if (owner < 0).any():
        raise ValueError("the scene leaves pixels empty: add a layer with an Everywhere outline")
    return disparity, owner, surface_x


def _paint(layers: list[Layer], owner: np.ndarray, surface_x: np.ndarray, rows: np.ndarray) -> np.ndarray:
    image = np.empty((*owner.shape, 3), dtype=np.float32)
    for index, layer in enumerate(layers):
        seen = owner == index
        if seen.any():
            image[seen] = layer.texture.sample(surface_x[seen], rows[seen])
    return image


def _occluded(layers: list[Layer], disparity: np.ndarray, rows: np.ndarray) -> np.ndarray:
    """Left pixels whose match ``x - d`` is outside the right image or hidden behind a nearer surface."""
    height, width = disparity.shape
    x_right = np.arange(width, dtype=np.float32)[None, :] - disparity
    occluded = x_right < 0
    for layer in layers:
        top, bottom = layer.outline.rows(height)
        if top >= bottom:
            continue
        xr, y = x_right[top:bottom], rows[top:bottom]
        x = layer.surface.left_x(xr, y)
        in_front = layer.outline.contains(x, y) & (layer.surface.at(x, y) > disparity[top:bottom]
                                                   + _OCCLUSION_TOLERANCE)
        occluded[top:bottom] |= in_front
    return occluded


def _clip_rows(top: float, bottom: float, height: int) -> tuple[int, int]:
    return max(0, int(np.floor(top))), min(height, int(np.ceil(bottom)))
