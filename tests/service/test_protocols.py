"""The protocols the layers are written against (service.features.Towers, service.protocols.StereoMatcher)
and what satisfies them: the real Matcher and towers, the trainer's PyTorch towers, the test stand-ins."""

from __future__ import annotations

import numpy as np
import pytest

from service.features import FeatureTowers, Towers
from service.matcher import Matcher, MatchOptions
from service.protocols import StereoMatcher
from tests.helpers import InstantMatcher, require_module
from tests.stand_in import MatcherRules, protocol_problems


def test_the_matcher_and_its_onnx_towers_satisfy_the_protocols() -> None:
    assert protocol_problems(Matcher, StereoMatcher) == []
    assert protocol_problems(FeatureTowers, Towers) == []
    matcher = Matcher.from_folder(threads=1)
    assert isinstance(matcher, StereoMatcher) and isinstance(matcher.towers, Towers)


@pytest.mark.torch
def test_the_trainers_torch_towers_satisfy_towers_and_run_in_the_matcher() -> None:
    require_module("torch")
    from training.evaluation import TorchTowers
    from training.networks import build_tower_pair

    assert protocol_problems(TorchTowers, Towers) == []
    towers = TorchTowers(build_tower_pair("37-4conv", channels=4).eval())
    assert isinstance(towers, Towers)
    image = np.random.default_rng(0).integers(0, 256, (40, 48, 3), dtype=np.uint8)
    result = Matcher(towers, threads=1)(image, image, MatchOptions(max_disparity=8))
    assert result.disparity.shape == (40, 48)


def test_the_stand_ins_satisfy_the_matcher_protocol() -> None:
    assert protocol_problems(InstantMatcher, StereoMatcher) == []
    assert isinstance(InstantMatcher(), StereoMatcher)


def test_a_stand_in_that_drifts_from_the_protocol_is_refused() -> None:
    # The check the stand-ins pass must fail on the defect it names: a call without the options, a
    # forgotten warm-up, a parameter the service never passes.
    with pytest.raises(TypeError, match=r"does not define warmup.*does not take 'options' as parameter 3"):
        class NoOptions(MatcherRules):
            def __call__(self, left, right):
                return None

    with pytest.raises(TypeError, match="requires 'scale', which the protocol never passes"):
        class ExtraParameter(MatcherRules):
            def warmup(self) -> None:
                pass

            def __call__(self, left, right, options, scale):
                return None

    class Bare:
        def __init__(self) -> None:
            self.manifest: dict = {}

        def warmup(self) -> None:
            pass

    assert not isinstance(Bare(), StereoMatcher)
    assert protocol_problems(Bare, StereoMatcher) == [
        "Bare does not define search_range", "Bare does not define plan", "Bare does not define __call__"]
