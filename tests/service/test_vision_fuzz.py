"""Schemathesis over the vision routes (in-process ASGI), with every check of tests/service/test_fuzz.py
(no 5xx, declared statuses, content types, headers and bodies, schema-valid data accepted but for the
rules the hooks forgive, schema-invalid data refused). Fewer examples than the other routes get, because
a valid render traces up to a million rays (size_px 1024, ~1-2 s). The multipart frames schemathesis
generates are random bytes, never PNG files: for `vision_motion` this fuzzes the multipart reader, the
PNG decoder's refusals and the JSON parts; frames that decode are covered by tests/service/test_vision_http.py.
"""

from __future__ import annotations

import tempfile

import schemathesis
from hypothesis import HealthCheck, settings
from schemathesis.core.failures import FailureGroup

from service.app import create_app
from service.settings import Settings
from tests.schemathesis_hooks import filter_failure
from tests.service.test_fuzz import CHECKS

_DATA = tempfile.TemporaryDirectory(prefix="capsule-rt-vision-fuzz-")
APP = create_app(Settings(data_dir=_DATA.name, log_level="error", load_builtins=False, max_queue=64))
APP.state.capsule.registry.load_builtins(True)
schema = schemathesis.openapi.from_asgi("/openapi.json", APP).include(path_regex=r"^/v1/vision/")


@schema.parametrize()
@settings(max_examples=30, deadline=None, derandomize=True, suppress_health_check=list(HealthCheck))
def test_vision_routes_never_fail_and_conform(case):
    response = case.call()
    try:
        case.validate_response(response, checks=CHECKS)
    except FailureGroup as group:
        from schemathesis.core.transport import Response

        answer = Response.from_any(response)
        kept = [f for f in group.exceptions if filter_failure(None, f, case, answer)]
        if kept:
            raise
