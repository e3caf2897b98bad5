"""Property-based fuzzing of the whole API with schemathesis (in-process ASGI).

For every operation of the OpenAPI document, schemathesis generates requests
from the schema (valid and invalid) and checks: no 5xx, the status code is one
the operation declares, the content type, headers and body conform to the
declared responses, schema-valid data is accepted and schema-invalid data
refused. The app runs with small limits (rays <= 2000, 3 interactions,
4 receivers, 20 trials), which its served schema states, and a 5 s deadline, so
generated requests stay cheap (a slow answer is never a failure here: no check
judges time). The refusals of schema-valid data for rules no JSON Schema can
state (a sample rate above twice the carrier...) are forgiven exactly as
``tests/schemathesis_hooks.py`` forgives them for ``schemathesis run --checks all``.
"""

from __future__ import annotations

import tempfile

import schemathesis
from hypothesis import HealthCheck, settings
from schemathesis.checks import not_a_server_error
from schemathesis.core.failures import FailureGroup
from schemathesis.specs.openapi.checks import (
    content_type_conformance,
    negative_data_rejection,
    positive_data_acceptance,
    response_headers_conformance,
    response_schema_conformance,
    status_code_conformance,
)

from service.app import create_app
from service.settings import Settings
from tests.schemathesis_hooks import filter_failure


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
            sweep_max_queue=1,  # sweeps accepted run in worker processes: one at a time, the rest get 503
            sweep_max_traces=2,
            sweep_workers=1,
            fullwave_max_queue=1,  # accepted full-wave jobs wait (the runner may not start here), the rest get 503
            fullwave_max_cell_updates=10**7,  # models are validated in milliseconds
            # every computation stops at 5 s (504, forgiven as documented): a generated evaluation of 200 traced
            # grid positions ran its full 60 s per example on a loaded machine, and the test for hours
            request_deadline_s=5.0,
        )
    )
    # Load the built-ins now: the ASGI transport of schemathesis may not run the lifespan.
    app.state.capsule.registry.load_builtins(True)
    return app


_DATA = tempfile.TemporaryDirectory(prefix="capsule-rt-fuzz-")
APP = _app(_DATA.name)
# the plot routes are fuzzed in tests/plots/test_plots_fuzz.py with fewer examples: each valid one draws a
# figure; the sweep routes in tests/sweeps/test_sweeps_fuzz.py, without the coverage phase (its boundary cases
# of the nested sweep spec take minutes to generate); the vision routes in tests/service/test_vision_fuzz.py
# (each valid render traces up to a million rays); the design routes in tests/design/test_http.py (each valid
# coverage plans thousands of skin candidates against the phantom, and accepted jobs trace for minutes)
schema = schemathesis.openapi.from_asgi("/openapi.json", APP).exclude(
    path_regex=r"^/v1/(plots/|sweeps|vision/|design/)")

CHECKS = [not_a_server_error, status_code_conformance, content_type_conformance, response_schema_conformance,
          response_headers_conformance, positive_data_acceptance, negative_data_rejection]


@schema.parametrize()
@settings(
    max_examples=100,
    deadline=None,
    derandomize=True,
    suppress_health_check=list(HealthCheck),
)
def test_api_never_fails_and_conforms(case):
    response = case.call()
    try:
        case.validate_response(response, checks=CHECKS)
    except FailureGroup as group:
        from schemathesis.core.transport import Response

        answer = Response.from_any(response)
        kept = [f for f in group.exceptions if filter_failure(None, f, case, answer)]
        if kept:
            raise


def test_fuzzing_left_no_partial_upload_behind():
    import os

    root = os.path.join(_DATA.name, "phantoms")
    leftovers = [e for e in os.listdir(root) if e.startswith((".tmp-", ".trash-"))] if os.path.isdir(root) else []
    assert leftovers == []
