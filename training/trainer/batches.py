"""Training batches as a pure function of (seed, example index): resume and DDP need no data-loader state.

Example ``i`` of a run draws everything from ``numpy.random.default_rng([seed, i])``: the synthetic scene
(generator seed ``seed * SEED_STRIDE + i``, always below the validation seeds), or which pair and window of
a dataset on disk, and the augmentation. With ``camera_draws`` K > 1, examples ``K j .. K j + K - 1``
share scene ``seed * SEED_STRIDE + j``, rendered once: the first is that seed's pair, the others the same
scene taken by the cameras of ``other_cameras(scene seed, k)``. Step ``s`` of a run
with ``world`` processes and ``batch`` examples per process uses examples ``(s * world + rank) * batch + k``:
every process sees different data, and a resumed run sees exactly the examples the uninterrupted run would
have.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import torch

from service.datasets import StereoSample, open_dataset
from service.datasets.readers import detect_kind
from training.data.evaluation_only import EVALUATION_ONLY, MOTORCYCLE_SPEC
from training.data.samples import Crop, PatchPairs, random_crop, random_patch_pairs
from training.data.synthetic import (
    DOWNSAMPLING,
    PHOTO_SHARE,
    VALIDATION_SEED,
    Photometric,
    Rectification,
    SyntheticConfig,
    check_share,
    other_cameras,
    photograph,
    render_scene,
)
from training.data.synthetic.scene import Rendering

SEED_STRIDE = 10_000_000            # examples per run seed; seeds 0..99 stay below VALIDATION_SEED
AUGMENTATIONS = ("none", "photometric")
# Measured (docs/training.md, "Schedule and augmentation"): 16 channels from scratch, 300 steps, same seed,
# "none" beat "photometric" on the synthetic validation split (bad-2 28.90 vs 29.26 %) and on Cones
# (15.69 vs 16.47 %): the generator's own camera effects are enough at these budgets.
DEFAULT_AUGMENTATION = "none"


@dataclasses.dataclass(frozen=True, kw_only=True)
class BatchSpec:
    """What one example looks like: crop size (dense), patch count (patch), disparity range, augmentation."""

    height: int = 128
    width: int = 256
    max_disparity: int = 96        # synthetic scenes only: nearest surface
    patches_per_pair: int = 32     # patch mode: patch pairs cut from each generated pair
    patch: int = 37                # patch mode: the tower's left patch side (the config's ``patch``)
    augmentation: str = DEFAULT_AUGMENTATION
    nonoccluded_only: bool = True  # an occluded pixel has no match to learn (where the data set says so)
    rectification_error: bool = False  # synthetic: the right view slightly misaligned (Rectification())
    vignetting: float = 0.0        # synthetic: per-view radial fall-off drawn from [0, vignetting]
    clean_views: float = 0.0       # synthetic: share of pairs rendered without camera effects (8-bit only)
    curved_surfaces: float = 0.0   # synthetic: share of objects that bulge towards the cameras, shaded
    fine_textures: float = 0.0     # synthetic: share of surfaces painted at twice the spatial frequency
    photo_textures: float = PHOTO_SHARE  # synthetic: share of surfaces painted with a photo
    # synthetic: share of scenes rendered and photographed at twice the size, then averaged 2 x 2 (a
    # downsampled photograph, as the real evaluation pairs are; SyntheticConfig.downsampling)
    downsampled_views: float = 0.0
    # synthetic: examples per rendered scene, each through freshly drawn cameras. The scene and its
    # rendering are ~85 % of a pair's cost and bound a GPU run's steps per second (docs/training.md).
    camera_draws: int = 1

    def __post_init__(self) -> None:
        if self.augmentation not in AUGMENTATIONS:
            raise ValueError(f"augmentation must be one of {AUGMENTATIONS}, got {self.augmentation!r}")
        if not 0.0 <= self.vignetting < 1.0:
            raise ValueError(f"vignetting must be in [0, 1), got {self.vignetting}")
        check_share("clean views", self.clean_views)
        check_share("curved surfaces", self.curved_surfaces)
        check_share("fine textures", self.fine_textures)
        check_share("photo textures", self.photo_textures)
        check_share("downsampled views", self.downsampled_views)
        if isinstance(self.camera_draws, bool) or not isinstance(self.camera_draws, int) \
                or self.camera_draws < 1:
            raise ValueError(f"camera draws must be a whole number >= 1, got {self.camera_draws!r}")
        if min(self.height, self.width) < 40:
            raise ValueError(f"crops must be at least 40 x 40 (the receptive field), got "
                             f"{self.height} x {self.width}")


class TrainingData:
    """Examples of ``--data``: ``synthetic`` (generated on the fly) or a dataset SPEC on disk."""

    def __init__(self, data: str, *, seed: int, spec: BatchSpec) -> None:
        if not 0 <= seed < VALIDATION_SEED // SEED_STRIDE:
            raise ValueError(f"seed must be in 0..{VALIDATION_SEED // SEED_STRIDE - 1}, got {seed}")
        self.data, self.seed, self.spec = data, seed, spec
        self.pairs: Sequence[StereoSample] | None = None
        if data != "synthetic":
            _refuse_evaluation_data(data)
            self.pairs = open_dataset(data)
        self.synthetic = SyntheticConfig(
            height=spec.height, width=spec.width, max_disparity=spec.max_disparity,
            photometric=Photometric(vignetting=(0.0, spec.vignetting)),
            rectification=Rectification() if spec.rectification_error else None,
            curved_surfaces=spec.curved_surfaces, fine_textures=spec.fine_textures,
            photo_probability=spec.photo_textures)
        # The last scene rendered, with its stream's state where the scene's draws end: the examples that
        # share a scene are consecutive, so one entry serves a whole batch's.
        self._scene: tuple[int, Rendering, dict] | None = None

    # Tags of the streams that draw a lever's per-example or per-scene choice, apart from the example's.
    _CLEAN_STREAM, _DOWNSAMPLED_STREAM = 1, 2

    @property
    def trained_range(self) -> list[int]:
        """Disparities the network sees in training (for the manifest)."""
        return [0, self.spec.max_disparity] if self.pairs is None else [0, 192]

    def sample(self, index: int) -> tuple[StereoSample, np.random.Generator]:
        """Pair of example ``index`` and the generator that cuts and augments it."""
        rng = np.random.default_rng([self.seed, index])
        if self.pairs is None:
            return self._synthetic(index), rng
        return self.pairs[int(rng.integers(len(self.pairs)))], rng

    def _synthetic(self, index: int) -> StereoSample:
        scene, draw = divmod(index, self.spec.camera_draws)
        seed = self.seed * SEED_STRIDE + scene
        config = self._config(index)
        if self._scene is None or self._scene[0] != seed:
            rendering, camera = render_scene(seed, config)
            self._scene = (seed, rendering, camera.bit_generator.state)
        _, rendering, state = self._scene
        if draw == 0:  # the seed's own cameras: with one draw per scene, exactly generate(seed)
            camera = np.random.Generator(np.random.PCG64())
            camera.bit_generator.state = state
        else:
            camera = other_cameras(seed, draw)
        return photograph(rendering, camera, config, name=f"synthetic-{seed}")

    def _config(self, index: int) -> SyntheticConfig:
        """The generator config of synthetic example ``index``: with probability ``downsampled_views`` (per
        scene) its scene is rendered and photographed at twice the size and averaged 2 x 2, and with
        probability ``clean_views`` (per example) it is taken without camera effects. Each choice has its
        own stream, so the crops (and, at 0, everything) stay those of a run without the levers."""
        config = self.synthetic
        scene = index // self.spec.camera_draws
        share = self.spec.downsampled_views
        if share and np.random.default_rng([self.seed, scene, self._DOWNSAMPLED_STREAM]).random() < share:
            config = dataclasses.replace(config, downsampling=DOWNSAMPLING)
        share = self.spec.clean_views
        if share and np.random.default_rng([self.seed, index, self._CLEAN_STREAM]).random() < share:
            config = dataclasses.replace(config, photometric=None)
        return config

    def crops(self, indices: Sequence[int]) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Dense batch: left, right [B, 3, h, w] in [0, 1] and disparity [B, h, w] (NaN unknown)."""
        crops = []
        for index in indices:
            sample, rng = self.sample(index)
            crop = random_crop(sample, rng, height=self.spec.height, width=self.spec.width,
                               nonoccluded_only=self.spec.nonoccluded_only)
            crops.append(self._augment(crop, rng))
        return (torch.stack([c.left for c in crops]), torch.stack([c.right for c in crops]),
                torch.stack([c.disparity for c in crops]))

    def patches(self, indices: Sequence[int]) -> PatchPairs:
        """Patch batch: ``patches_per_pair`` patch pairs from each example's pair."""
        parts = []
        for index in indices:
            sample, rng = self.sample(index)
            pairs = random_patch_pairs(sample, rng, count=self.spec.patches_per_pair, patch=self.spec.patch,
                                       nonoccluded_only=self.spec.nonoccluded_only)
            left, right = self._photometric(pairs.left, pairs.right, rng)
            parts.append(dataclasses.replace(pairs, left=left, right=right))
        return PatchPairs(*(torch.cat([getattr(p, f.name) for p in parts])
                            for f in dataclasses.fields(PatchPairs)))

    def _augment(self, crop: Crop, rng: np.random.Generator) -> Crop:
        left, right = self._photometric(crop.left[None], crop.right[None], rng)
        return dataclasses.replace(crop, left=left[0], right=right[0])

    def _photometric(self, left: torch.Tensor, right: torch.Tensor, rng: np.random.Generator
                     ) -> tuple[torch.Tensor, torch.Tensor]:
        """Colour changes shared by both views (channel order, grey) plus per-view contrast/brightness,
        so the towers learn to match structure, not absolute colour (real pairs differ more than the
        generator's camera effects alone)."""
        if self.spec.augmentation == "none":
            return left, right
        order = torch.from_numpy(rng.permutation(3))
        left, right = left[:, order], right[:, order]
        if rng.random() < 0.2:
            left = left.mean(dim=1, keepdim=True).expand_as(left)
            right = right.mean(dim=1, keepdim=True).expand_as(right)
        views = []
        for view in (left, right):
            contrast, brightness = rng.uniform(0.7, 1.3), rng.uniform(-0.1, 0.1)
            mean = view.mean(dim=(1, 2, 3), keepdim=True)
            views.append(((view - mean) * contrast + mean + brightness).clamp(0.0, 1.0).contiguous())
        return views[0], views[1]


def _refuse_evaluation_data(data: str) -> None:
    kind, _, argument = data.partition(":")
    if kind == "synthetic":
        raise ValueError(f"{data!r} is the synthetic validation split (best.pt is selected on it): train on "
                         "'synthetic', the generator's training seeds")
    if kind == MOTORCYCLE_SPEC:
        raise ValueError(f"{data!r} is an evaluation pair (Middlebury 2014's Motorcycle): training on it "
                         "is not allowed")
    path = Path(argument or data)
    named = any(name in str(path.resolve()) for name in EVALUATION_ONLY)
    if kind == "cones" or named or (path.is_dir() and not argument and detect_kind(path) == "cones"):
        raise ValueError(f"{data!r} is an evaluation pair (Cones layout): training on it is not allowed")
