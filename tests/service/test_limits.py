"""The server's limits, declared once (service.limits): the bound on the field, the served schema, the
sweep spec's schema and the one "lower or refuse" rule all follow the same settings."""

from __future__ import annotations

import json

import pytest

from service.admission import lower_or_refuse
from service.app import create_app
from service.errors import Unprocessable
from service.limits import CEILINGS, LIMIT_KEY, Limits, capped

SMALL = {"max_rays": 2000, "max_interactions": 3, "max_receivers": 4, "max_band_points": 11, "max_trials": 20}


def _marked(node, path=()):
    """Every (path, setting) marked in a JSON Schema."""
    if isinstance(node, dict):
        if LIMIT_KEY in node:
            yield path, node[LIMIT_KEY]
        for key, value in node.items():
            yield from _marked(value, (*path, key))
    elif isinstance(node, list):
        for i, value in enumerate(node):
            yield from _marked(value, (*path, i))


def _at(node, path):
    for key in path:
        node = node[key]
    return node


def _bounds(spec: dict) -> list[int]:
    return [branch[k] for branch in [spec, *spec.get("anyOf", []), *spec.get("oneOf", [])]
            for k in ("maximum", "maxItems") if k in branch]


@pytest.fixture(scope="module")
def raw_and_served(tmp_path_factory):
    """The app's document before the limits are applied (FastAPI's own generator) and as served."""
    from service.settings import Settings

    settings = Settings(data_dir=tmp_path_factory.mktemp("data"), log_level="warning", **SMALL)
    app = create_app(settings)
    served = app.openapi()
    app.openapi_schema = None
    from fastapi.openapi.utils import get_openapi

    raw = get_openapi(title=app.title, version=app.version, routes=app.routes)
    return raw, served


def test_every_marked_bound_is_lowered_to_its_setting_and_the_marker_is_not_served(raw_and_served):
    raw, served = raw_and_served
    marked = list(_marked(raw))
    # the request fields a setting caps: channel, ranging, localization, tracking, full-wave, design, sweeps
    assert len(marked) >= 20, marked
    assert LIMIT_KEY not in json.dumps(served)
    for path, setting in marked:
        if path[0] == "components" and path[2] not in served["components"]["schemas"]:
            continue
        bounds = _bounds(_at(served, path))
        assert bounds and all(b <= SMALL[setting] for b in bounds), (path, setting, bounds)
        default = _at(served, path).get("default")
        assert not isinstance(default, int) or default <= SMALL[setting], (path, default)


def test_the_served_sweep_spec_follows_the_settings(raw_and_served):
    _, served = raw_and_served
    spec = served["paths"]["/v1/sweeps"]["post"]["requestBody"]["content"]["application/json"]["schema"]
    assert spec["properties"]["channel"]["properties"]["rays"]["maximum"] == SMALL["max_rays"]
    assert spec["properties"]["trials"]["maximum"] == spec["properties"]["trials"]["default"] == SMALL["max_trials"]
    assert spec["example"]["channel"]["max_interactions"] <= SMALL["max_interactions"]
    # a fix: the sweep's receivers follow max_receivers as the job's own limits do (service.sweep_jobs)
    assert [b["maxItems"] for b in spec["properties"]["receivers"]["oneOf"] if "maxItems" in b] == [4]


def test_lower_schema_lowers_examples_of_nested_objects():
    node = {"type": "object", "example": {"channel": {"rays": 9000}, "trials": 50},
            "properties": {"channel": {"type": "object", "properties": {
                "rays": {"type": "integer", "maximum": 10**6, LIMIT_KEY: "max_rays"}}},
                "trials": {"type": "integer", "maximum": 10**4, "default": 100, LIMIT_KEY: "max_trials"}}}
    Limits({**CEILINGS, "max_rays": 1000, "max_trials": 30}).lower_schema(node)
    assert node["example"] == {"channel": {"rays": 1000}, "trials": 30}
    assert node["properties"]["trials"] == {"type": "integer", "maximum": 30, "default": 30}
    assert node["properties"]["channel"]["properties"]["rays"] == {"type": "integer", "maximum": 1000}


def test_lower_or_refuse(make_settings):
    settings = make_settings(max_rays=2000)
    assert lower_or_refuse(None, "max_rays", settings, ("rays",), default=100_000) == 2000
    assert lower_or_refuse(1500, "max_rays", settings, ("rays",), default=100_000) == 1500
    with pytest.raises(Unprocessable) as err:
        lower_or_refuse(2001, "max_rays", settings, ("channel", "rays"), default=100)
    assert err.value.loc == ["body", "channel", "rays"] and "2000" in err.value.reason
    with pytest.raises(ValueError):
        lower_or_refuse(1, "max_everything", settings, ("x",), default=1)
    with pytest.raises(ValueError):
        capped("max_everything")
