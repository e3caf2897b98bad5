"""Property-based fuzzing of the whole API with schemathesis (in-process ASGI).

For every operation of the OpenAPI document, schemathesis generates requests
from the schema (valid and invalid) and checks: no 5xx, the status code is one
the operation declares, the content type and the body conform to the declared
response schema. The app runs with small limits (rays <= 2000, 3 interactions,
4 receivers) so generated channel requests stay cheap; larger values get the
documented 422.
"""

from __future__ import annotations

import schemathesis
from hypothesis import HealthCheck, settings
from schemathesis.checks import not_a_server_error
from schemathesis.specs.openapi.checks import (
    content_type_conformance,
    response_schema_conformance,
    status_code_conformance,
)

from service.app import create_app
from service.settings import Settings


def _app(tmp_dir: str):
    app = create_app(
        Settings(
            data_dir=tmp_dir,
            log_level="error",
            max_rays=2000,
            max_interactions=3,
            max_receivers=4,
            max_band_points=11,
            max_trials=20,
            max_upload_bytes=64 * 1024,
            max_concurrency=4,
            max_queue=64,
        )
    )
    # Load the built-ins now: the ASGI transport of schemathesis may not run the lifespan.
    app.state.capsule.registry.load_builtins(True)
    return app


import tempfile

_DATA = tempfile.TemporaryDirectory(prefix="capsule-rt-fuzz-")
APP = _app(_DATA.name)
# the plot routes are fuzzed in tests/plots/test_plots_fuzz.py with fewer examples: each valid one draws a figure
schema = schemathesis.openapi.from_asgi("/openapi.json", APP).exclude(path_regex=r"^/v1/plots/")

CHECKS = [not_a_server_error, status_code_conformance, content_type_conformance, response_schema_conformance]


@schema.parametrize()
@settings(
    max_examples=100,
    deadline=None,
    derandomize=True,
    suppress_health_check=list(HealthCheck),
)
def test_api_never_fails_and_conforms(case):
    case.call_and_validate(checks=CHECKS)


def test_fuzzing_left_no_partial_upload_behind():
    import os

    root = os.path.join(_DATA.name, "phantoms")
    leftovers = [e for e in os.listdir(root) if e.startswith((".tmp-", ".trash-"))] if os.path.isdir(root) else []
    assert leftovers == []
