"""The tracer's constants that the request models state, copied here so that the models (and the
typed client, :mod:`service.client`) import neither the tracer nor gprMax's wrapper: ``import
service.client`` loads no ``raytrace``, numba or embreex. Each copy names its source;
``tests/service/test_schema_constants.py`` fails the moment one drifts from it."""

from __future__ import annotations

# raytrace.physics.tissues: the dielectric model's frequency range [Hz] and its tissues
FREQUENCY_MIN_HZ = 10.0
FREQUENCY_MAX_HZ = 20000000000.0
TISSUE_NAMES = (
    'skin_dry',
    'skin_wet',
    'fat_not_infiltrated',
    'fat_average_infiltrated',
    'muscle',
    'stomach',
    'small_intestine',
    'colon',
    'liver',
    'kidney',
    'spleen',
    'heart',
    'lung_inflated',
    'lung_deflated',
    'bone_cortical',
    'bone_cancellous',
    'bone_marrow_infiltrated',
    'bone_marrow_not_infiltrated',
    'blood',
    'gall_bladder_bile',
    'gall_bladder',
    'bladder',
    'cartilage',
    'aorta',
    'tendon',
    'nerve',
    'air',
)

# raytrace.body.gltf: the upload manifest's rules
NAME_PATTERN = '^[A-Za-z0-9][A-Za-z0-9_.-]{0,63}$'
MAX_NAME_CHARS = 128
MAX_DESCRIPTION_CHARS = 2000
MAX_ORGANS = 256
MAX_SITES = 1024
MAX_PERMITTIVITY = 1000.0
MAX_CONDUCTIVITY_S_PER_M = 1000.0
UNITS = {'m': 1.0, 'mm': 0.001}
MIN_EXTENT_M = 0.01
MAX_EXTENT_M = 20.0

# raytrace.spec: the channel request's ceiling and defaults (ChannelSpec's fields)
MAX_DYNAMIC_RANGE_DB = 300.0
SPEC_DEFAULTS = {
    "phantom": 'torso',
    "frequency_hz": 402000000.0,
    "max_interactions": 6,
    "rays": 100000,
    "dynamic_range_db": 80.0,
    "near_field": True,
}

# fullwave.model.FdtdOptions: the full-wave request's FDTD defaults
FDTD_DEFAULTS = {"cell_m": 0.002, "margin_m": 0.02, "pml_cells": 10}
