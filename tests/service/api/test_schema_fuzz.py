"""Schema fuzzing: schemathesis drives the app in process from its own OpenAPI schema.

Every operation gets generated requests (valid and invalid query parameters, headers and bodies);
each answer must not be a 5xx and must conform to the schema (documented status, content type,
headers and body). The stereo routes are fuzzed twice per example: with the generated body (random
bytes as images: the error paths) and with the generated parameters around a real 16x24 pair (the
inference path). Examples are bounded and derandomised so the run is reproducible and short.

What is generated is a function of the schema and Hypothesis' derandomised seed only, so the file's
result does not depend on which tests ran before it. Hypothesis also draws "local constants": literals
of every project module imported so far (tests included), re-read whenever ``sys.modules`` grows; the
same derandomised test therefore drew different requests alone and inside the whole suite (alone, a
multipart body whose violation schemathesis' encoder drops: see ``negative_data_rejection_as_sent``).
``_no_imported_constants`` gives it an empty pool while this file runs.
"""

from __future__ import annotations

import io
import time
from collections.abc import Iterator
from email.parser import BytesParser
from email.policy import HTTP

import numpy as np
import pytest
import schemathesis
from hypothesis import HealthCheck, settings
from hypothesis.internal.conjecture import providers
from PIL import Image
from schemathesis.core.failures import AcceptedNegativeData, FailureGroup
from schemathesis.core.parameters import ParameterLocation
from schemathesis.generation import GenerationMode
from schemathesis.generation.meta import (
    CaseMetadata,
    ComponentInfo,
    FuzzingPhaseData,
    GenerationInfo,
    PhaseInfo,
    TestPhase,
)

from service.api import Settings, create_app
from service.matcher import Matcher

MAX_EXAMPLES = 100
STEREO_PATHS = ("/disparity", "/depth", "/pointcloud")
PAIR_PARTS = ("left", "right")


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
def _no_imported_constants() -> Iterator[None]:
    """Hypothesis' pool of literals from imported local modules, empty while this file runs.

    The pool grows with whatever the tests before this file imported, and its draws (e.g. p2 = 0.05
    instead of 0.01) change every example after them. ``_get_local_constants`` is Hypothesis-internal:
    if it moves, this fixture fails rather than letting the order dependence back in silently.
    """
    assert callable(providers._get_local_constants), "hypothesis moved _get_local_constants"
    saved = providers._get_local_constants
    providers._get_local_constants = providers.Constants
    providers.CONSTANTS_CACHE.cache.clear()
    try:
        yield
    finally:
        providers._get_local_constants = saved
        providers.CONSTANTS_CACHE.cache.clear()


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


def sent_multipart_parts(response) -> list[tuple[str, bool]] | None:
    """(name, is a file part) for each part of the multipart/form-data body actually sent, or None."""
    body = response.request.body
    content_type = response.request.headers.get("Content-Type", "")
    if not isinstance(body, bytes) or not content_type.startswith("multipart/form-data"):
        return None
    message = BytesParser(policy=HTTP).parsebytes(f"Content-Type: {content_type}\r\n\r\n".encode() + body)
    return [(part.get_param("name", header="content-disposition"), part.get_filename() is not None)
            for part in message.iter_parts()]


def negative_data_rejection_as_sent(ctx, response, case):
    """schemathesis' negative_data_rejection, judged on the multipart body as it went over the wire.

    A negative body can lose its violation when schemathesis encodes it: an extra property whose value
    is an empty list (``{"left": ..., "right": ..., "": []}``, violating ``additionalProperties``)
    becomes no part at all, so the server receives exactly the files ``left`` and ``right``, a
    schema-valid body, and rightly answers it. When the body was the only negated component and what
    was sent is exactly one file part per schema property, the request is valid and the check has
    nothing to judge; in every other case (a stray part, a missing or text part, a negated query or
    header) the built-in check runs unchanged.
    """
    meta = case.meta
    only_body_negated = meta is not None and meta.is_negative_at(ParameterLocation.BODY) and not any(
        component.mode.is_negative for location, component in meta.components.items()
        if location != ParameterLocation.BODY)
    if only_body_negated:
        parts = sent_multipart_parts(response)
        if parts is not None and sorted(parts) == [(name, True) for name in PAIR_PARTS]:
            return None
    return schemathesis.checks.negative_data_rejection(ctx, response, case)


# Checks configured per operation, each with its reason; every check not named here runs everywhere.
# positive_data_acceptance is left out on every operation: a schema-valid request may still be refused for
# what no schema can say (random bytes as an image: 415; a range over this server's limits or the image
# width: 400/413).
DEFAULT_CHECKS: dict = {"excluded_checks": [schemathesis.checks.positive_data_acceptance]}
# negative_data_rejection (a request that breaks the schema must not be answered 2xx) runs on every
# operation; on those with a multipart body it is judged on the body as sent, because schemathesis'
# encoder can drop the very property that made a generated body negative.
MULTIPART_CHECKS: dict = {
    "excluded_checks": [*DEFAULT_CHECKS["excluded_checks"], schemathesis.checks.negative_data_rejection],
    "additional_checks": [negative_data_rejection_as_sent],
}
PER_OPERATION = {f"POST {path}": MULTIPART_CHECKS for path in STEREO_PATHS}


def checks_for(case: schemathesis.Case) -> dict:
    return PER_OPERATION.get(f"{case.method.upper()} {case.path}", DEFAULT_CHECKS)


def test_multipart_operations_are_the_configured_ones() -> None:
    multipart = {f"{method.upper()} {path}" for path, item in schema.raw_schema["paths"].items()
                 for method, operation in item.items()
                 if "multipart/form-data" in operation.get("requestBody", {}).get("content", {})}
    assert multipart == set(PER_OPERATION)


@schema.parametrize()
@settings(max_examples=MAX_EXAMPLES, derandomize=True, deadline=None, database=None,
          suppress_health_check=list(HealthCheck))
def test_no_server_error_and_no_schema_violation(case: schemathesis.Case) -> None:
    case.call_and_validate(**checks_for(case))
    if case.path in STEREO_PATHS:
        # The same query and headers around a real pair: reaches decoding, the matcher and every encoder.
        real_pair = case.operation.Case(
            query=case.query, headers=case.headers, body={"left": LEFT, "right": RIGHT},
            media_type="multipart/form-data",
        )
        real_pair.call_and_validate(**checks_for(real_pair))


def _negative_body_case(body: dict) -> schemathesis.Case:
    """A POST /disparity case whose body alone is negated (violates ``additionalProperties``)."""
    meta = CaseMetadata(
        generation=GenerationInfo(time=0.0, mode=GenerationMode.NEGATIVE),
        components={ParameterLocation.BODY: ComponentInfo(mode=GenerationMode.NEGATIVE)},
        phase=PhaseInfo(name=TestPhase.FUZZING, data=FuzzingPhaseData(
            description="violates `additionalProperties`", parameter=None,
            parameter_location=ParameterLocation.BODY, location=None)),
    )
    return schema["/disparity"]["POST"].Case(body=body, media_type="multipart/form-data", _meta=meta)


def test_multipart_body_that_loses_its_violation_is_judged_as_sent() -> None:
    # The false positive the fuzzer once drew: the extra property "" holds [] and is sent as no part.
    case = _negative_body_case({"left": LEFT, "right": RIGHT, "": []})
    response = case.call()
    assert sent_multipart_parts(response) == [("left", True), ("right", True)]
    assert response.status_code == 200  # a valid request, rightly answered
    case.validate_response(response, checks=[negative_data_rejection_as_sent], **checks_for(case))


def test_multipart_stray_part_accepted_is_still_a_failure() -> None:
    case = _negative_body_case({"left": LEFT, "right": RIGHT, "extra": b"x"})
    response = case.call()
    assert ("extra", False) in sent_multipart_parts(response) and response.status_code == 400
    case.validate_response(response, checks=[negative_data_rejection_as_sent])  # refused: passes
    response.status_code = 200  # the defect put back: a server that ignores the stray part
    with pytest.raises(FailureGroup, match="1 distinct failure") as failure:
        case.validate_response(response, checks=[negative_data_rejection_as_sent])
    assert isinstance(failure.value.exceptions[0], AcceptedNegativeData)
