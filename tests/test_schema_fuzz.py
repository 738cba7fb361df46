"""Schema fuzzing: schemathesis drives the app in process from its own OpenAPI schema.

Every operation gets generated requests (valid and invalid query parameters, headers and bodies);
each answer must not be a 5xx and must conform to the schema (documented status, content type,
headers and body). The stereo routes are fuzzed twice per example: with the generated body (random
bytes as images: the error paths) and with the generated parameters around a real 16x24 pair (the
inference path). Examples are bounded and derandomised so the run is reproducible and short.
"""

from __future__ import annotations

import io
import time

import numpy as np
import pytest
import schemathesis
from hypothesis import HealthCheck, settings
from PIL import Image

from service.api import Settings, create_app
from service.matcher import Matcher

MAX_EXAMPLES = 100
STEREO_PATHS = ("/disparity", "/depth", "/pointcloud")


def _png(image: np.ndarray) -> bytes:
    buffer = io.BytesIO()
    Image.fromarray(image).save(buffer, format="PNG")
    return buffer.getvalue()


_TEXTURE = np.random.default_rng(3).integers(0, 256, (16, 28, 3), dtype=np.uint8)
LEFT, RIGHT = _png(_TEXTURE[:, :24]), _png(_TEXTURE[:, 4:])

# The real default model, loaded once; small limits so that generated parameters reach every limit.
APP = create_app(
    Settings(queue_size=2, max_body_bytes=64_000, max_pixels=16 * 24 * 4, max_disparity=64,
             max_cost_cells=16 * 24 * 24),
    matcher=Matcher.from_folder(threads=1),
)
schema = schemathesis.openapi.from_asgi("/openapi.json", APP)


@pytest.fixture(scope="module", autouse=True)
def _warm() -> None:
    # schemathesis runs the app's lifespan in its own event-loop thread; wait for the warm-up it starts.
    deadline = time.monotonic() + 120
    while not APP.state.inference.ready:
        assert APP.state.inference.failure is None, APP.state.inference.failure
        assert time.monotonic() < deadline, "the app did not warm up"
        time.sleep(0.05)


def test_schema_lists_every_route() -> None:
    paths = set(schema.raw_schema["paths"])
    assert {*STEREO_PATHS, "/healthz", "/readyz", "/metrics", "/v1/model"} <= paths


# positive_data_acceptance is left out: a schema-valid request may still be refused for what no schema can
# say (random bytes as an image: 415; a range over this server's limits or the image width: 400/413).
# negative_data_rejection stays: a request that breaks the schema must not be answered 2xx.
EXCLUDED = [schemathesis.checks.positive_data_acceptance]


@schema.parametrize()
@settings(max_examples=MAX_EXAMPLES, derandomize=True, deadline=None, database=None,
          suppress_health_check=list(HealthCheck))
def test_no_server_error_and_no_schema_violation(case: schemathesis.Case) -> None:
    case.call_and_validate(excluded_checks=EXCLUDED)
    if case.path in STEREO_PATHS:
        # The same query and headers around a real pair: reaches decoding, the matcher and every encoder.
        real_pair = case.operation.Case(
            query=case.query, headers=case.headers, body={"left": LEFT, "right": RIGHT},
            media_type="multipart/form-data",
        )
        real_pair.call_and_validate(excluded_checks=EXCLUDED)
