"""Schemathesis over the sweep routes, with every check of tests/service/test_fuzz.py and its
forgiving hooks (tests/schemathesis_hooks.py: the spec's rules that depend on the phantom or relate
fields). No coverage phase: its boundary cases of the nested sweep spec take minutes to generate;
the spec's limits are tested one by one in test_spec.py. The app allows one sweep job at a time
(the others get 503) of at most two traces, so accepted jobs stay cheap."""

from __future__ import annotations

import schemathesis
from hypothesis import HealthCheck, settings
from schemathesis.core.failures import FailureGroup

from tests.schemathesis_hooks import filter_failure
from tests.service.test_fuzz import APP, CHECKS

schema = schemathesis.openapi.from_asgi("/openapi.json", APP).include(path_regex=r"^/v1/sweeps")
schema.config.phases.coverage.enabled = False


@schema.parametrize()
@settings(max_examples=25, deadline=None, derandomize=True, suppress_health_check=list(HealthCheck))
def test_sweep_routes_never_fail_and_conform(case):
    response = case.call()
    try:
        case.validate_response(response, checks=CHECKS)
    except FailureGroup as group:
        from schemathesis.core.transport import Response

        answer = Response.from_any(response)
        if [f for f in group.exceptions if filter_failure(None, f, case, answer)]:
            raise
