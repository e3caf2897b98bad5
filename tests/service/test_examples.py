"""Every request example the server serves (in /openapi.json, shown by /docs) is one that server accepts
(issue 34, item 10: the RenderRequest example asked for s_m 1.2 on the default torso, whose GI tract is
0.69 m long, and got a 422). The server has lowered limits (rays, trials), which its served examples follow
(service.app: lowered limits clamp the examples), so each example runs in a second or so; the job
examples (a sweep, full-wave cross-checks) are validated as their submission validates them, without
queueing anything. (Interactions stay at their ceiling: the evaluation's default of 6 reaches every sensor
of its example, 4 does not.)"""

from __future__ import annotations

import pytest
from fastapi.testclient import TestClient

from service.app import create_app

#: Operations whose examples start jobs: validated in place, not queued (a sweep or a coverage would run on a
#: worker pool, a full-wave job gprMax).
JOBS = {"submit_sweep", "submit_fullwave", "submit_coverage", "submit_layout"}


def _examples(schema: dict) -> list[tuple[str, int, str, dict]]:
    components = schema["components"]["schemas"]
    out = []
    for path, item in schema["paths"].items():
        for method, op in item.items():
            content = op.get("requestBody", {}).get("content", {})
            body = content.get("application/json", {}).get("schema")
            if method != "post" or body is None:
                continue
            ref = body.get("$ref")
            examples = components[ref.rsplit("/", 1)[1]].get("examples", []) if ref else body.get("examples") or (
                [body["example"]] if "example" in body else [])
            out += [(op["operationId"], k, path, example) for k, example in enumerate(examples)]
    return out


@pytest.fixture(scope="module")
def client(tmp_path_factory):
    from service.settings import Settings

    settings = Settings(data_dir=tmp_path_factory.mktemp("examples"), log_level="error", max_rays=20_000,
                        max_trials=20)
    with TestClient(create_app(settings), raise_server_exceptions=False) as c:
        yield c


def _cases():
    from service.settings import Settings

    app = create_app(Settings(data_dir="/nonexistent-capsule-rt-data", log_level="error", load_builtins=False,
                              max_rays=20_000, max_trials=20))
    return [pytest.param(op, path, example, id=f"{op}[{k}]") for op, k, path, example in _examples(app.openapi())]


def test_every_operation_with_a_body_shows_an_example():
    from service.settings import Settings

    app = create_app(Settings(data_dir="/nonexistent-capsule-rt-data", log_level="error", load_builtins=False))
    shown = {op for op, *_ in _examples(app.openapi())}
    assert {"compute_channel", "vision_render", "localize", "localize_evaluate", "submit_sweep"} <= shown


@pytest.mark.parametrize("op, path, example", _cases())
def test_every_served_example_is_accepted(client, op, path, example):
    if op == "submit_sweep":
        from sweeps.plan import make_plan
        from sweeps.spec import SweepSpec

        jobs = client.app.state.sweeps
        spec = SweepSpec.from_dict(example, jobs.limits)
        phantom = client.app.state.capsule.registry.get(spec["phantom"])
        assert make_plan(spec, phantom, spec["phantom"], jobs.limits).n_positions > 0
        return
    if op == "submit_fullwave":
        from service.schemas.fullwave import FullwaveRequest

        client.app.state.fullwave._validate(FullwaveRequest.model_validate(example))
        return
    if op == "submit_coverage":
        from design import coverage as cov

        jobs = client.app.state.coverage
        spec = cov.normalise_spec(example, jobs.limits)
        phantom = client.app.state.capsule.registry.get(spec["phantom"])
        assert cov.make_plan(spec, phantom, jobs.limits, client.app.state.capsule.settings.tracer_config()).links > 0
        return
    if op == "submit_layout":  # its coverage is an id to a done job: the layout itself is checked
        from design.layout import normalise_layout

        normalise_layout({k: v for k, v in example.items() if k != "coverage"})
        return
    assert op not in JOBS
    r = client.post(path, json=example, headers={"Accept": "application/json"} if op == "vision_render" else {})
    assert r.status_code == 200, (op, r.text[:500])
