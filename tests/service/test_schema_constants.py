"""The request models' copies of the tracer's constants (service/schemas/constants.py, kept there so the
typed client imports no tracer) equal their sources, and the names they restate are the registries': a
change in raytrace, fullwave or tracking fails here until the copy follows."""

from __future__ import annotations

from dataclasses import fields

from fullwave.model import FdtdOptions
from raytrace.body import gltf
from raytrace.physics import tissues
from raytrace.spec import MAX_DYNAMIC_RANGE_DB, ChannelSpec
from service.schemas import constants as copy


def test_the_tissue_model_constants_are_the_tracers():
    assert (copy.FREQUENCY_MIN_HZ, copy.FREQUENCY_MAX_HZ) == (tissues.FREQUENCY_MIN_HZ, tissues.FREQUENCY_MAX_HZ)
    assert tuple(copy.TISSUE_NAMES) == tuple(tissues.TISSUE_NAMES)


def test_the_manifest_rules_are_the_loaders():
    assert copy.NAME_PATTERN == gltf.NAME_PATTERN.pattern
    for name in ("MAX_NAME_CHARS", "MAX_DESCRIPTION_CHARS", "MAX_ORGANS", "MAX_SITES", "MAX_PERMITTIVITY",
                 "MAX_CONDUCTIVITY_S_PER_M", "MIN_EXTENT_M", "MAX_EXTENT_M"):
        assert getattr(copy, name) == getattr(gltf, name), name
    assert dict(copy.UNITS) == dict(gltf.UNITS)


def test_the_channel_and_fdtd_defaults_are_their_specs():
    assert copy.MAX_DYNAMIC_RANGE_DB == MAX_DYNAMIC_RANGE_DB
    defaults = {f.name: f.default for f in fields(ChannelSpec)}
    assert copy.SPEC_DEFAULTS == {k: defaults[k] for k in copy.SPEC_DEFAULTS}
    fd = FdtdOptions()
    assert copy.FDTD_DEFAULTS == {k: getattr(fd, k) for k in copy.FDTD_DEFAULTS}


def test_the_track_request_offers_the_trackers_registry():
    """POST /v1/track's ``tracker`` restates tracking.TRACKERS (the models do not import the tracker,
    which loads the tracer); the journey evaluation's filters are registered trackers."""
    from evaluation.tracking import FILTERS
    from service.schemas.tracking import TrackRequest
    from tracking import TRACKERS

    assert tuple(TrackRequest.model_json_schema()["properties"]["tracker"]["enum"]) == tuple(TRACKERS)
    assert set(FILTERS.values()) <= set(TRACKERS)
