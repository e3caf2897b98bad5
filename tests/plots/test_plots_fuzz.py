"""Schemathesis over the plot routes (in-process ASGI): valid and invalid bodies generated from each
kind's schema never get a 5xx, and every answer is a declared status with a declared content type
(an image for 200, the error JSON otherwise). Fewer examples than tests/service/test_fuzz.py uses
for the other routes, and no coverage phase (its ~1100 boundary cases draw ~320 figures, ~100 s;
the caps it probes are tested one by one in test_plots_figures.py / test_plots_service.py), because
each valid example draws a whole figure (0.1-7 s). ``CAPSULE_RT_PLOT_FUZZ_COVERAGE=1`` turns the
coverage phase on for a thorough run."""

from __future__ import annotations

import os
import tempfile
import warnings

import schemathesis
from hypothesis import HealthCheck, settings
from schemathesis.checks import not_a_server_error
from schemathesis.specs.openapi.checks import content_type_conformance, status_code_conformance

from service.app import create_app
from service.settings import Settings

_DATA = tempfile.TemporaryDirectory(prefix="capsule-rt-plot-fuzz-")
APP = create_app(Settings(data_dir=_DATA.name, log_level="error", load_builtins=False, max_queue=64))
schema = schemathesis.openapi.from_asgi("/openapi.json", APP).include(path_regex=r"^/v1/plots/")
schema.config.phases.coverage.enabled = os.environ.get("CAPSULE_RT_PLOT_FUZZ_COVERAGE") == "1"


@schema.parametrize()
@settings(max_examples=15, deadline=None, derandomize=True, suppress_health_check=list(HealthCheck))
def test_plot_routes_never_fail_and_conform(case):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)  # generated titles use glyphs no font has
        case.call_and_validate(checks=[not_a_server_error, status_code_conformance, content_type_conformance])
