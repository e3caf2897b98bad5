"""The link model by reciprocity (design.model) against the sensors' own travel-time fields.

Oracle: :func:`evaluation.fields.sensor_fields`, one eikonal field per sensor (what the model-based
fix and its bound use), evaluated at the capsule: T_s(x) and grad T_s(x). The design module instead
builds fields from the capsule and differences them (T_x(s), (T_{x+h e} - T_{x-h e})(s) / 2h). Both
are fast-marching solutions on the same grid, not the same computation: the source sits at the other
end. Tolerances: delays within the stated discretisation error n_max h / c of either field (they
measured 66 ps against 124 ps); gradient directions within 4 degrees (median) and 15 degrees (max),
magnitudes within 10 % (measured on the torso, 84 links: 1.8 / 9.0 degrees, 0.94-1.03).
"""

from __future__ import annotations

import numpy as np

from design.model import link_model
from evaluation.fields import sensor_fields
from raytrace.body.torso import default_torso


def test_reciprocal_fields_agree_with_the_sensors_own_fields():
    phantom = default_torso()
    sites = ["belt_anterior", "belt_left", "upper_posterior", "upper_right"]
    sensors = np.array([phantom.sites[s].position_m for s in sites])
    line = phantom.centrelines["gi_tract"]
    capsules = np.asarray(line.point_m(np.array([0.05, 0.45])))
    model = link_model(phantom, capsules, sensors, 402e6, 0.004)
    fields = sensor_fields(phantom, sensors, 402e6, 0.004, delay_kind="phase")  # link_model's default index
    angles, ratios = [], []
    for p, x in enumerate(capsules):
        t, g = fields.evaluate(x)
        assert np.all(np.abs(model["eikonal_delay_s"][p] - t) <= fields.discretisation_error_s)
        a = model["gradient_s_per_m"][p]
        cos = np.sum(a * g, axis=1) / np.linalg.norm(a, axis=1) / np.linalg.norm(g, axis=1)
        angles += np.degrees(np.arccos(np.clip(cos, -1.0, 1.0))).tolist()
        ratios += (np.linalg.norm(a, axis=1) / np.linalg.norm(g, axis=1)).tolist()
    assert np.median(angles) < 4.0 and max(angles) < 15.0, angles
    assert 0.9 < min(ratios) and max(ratios) < 1.1, ratios
