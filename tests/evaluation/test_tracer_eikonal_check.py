"""The tracer against an oracle that shares no code with it: the eikonal first arrival
(voxelized torso, scikit-fmm) is Fermat's minimum over all continuous paths, so no traced
path may arrive earlier than it minus the grid's stated discretisation error.

Grid: 4 mm cells (the default), stated error n_max h / c = 124 ps (n_max = 9.32, small
intestine at 402 MHz). On this torso the traced first arrivals come no earlier than 88 ps
before the eikonal ones; the pairs where the eikonal arrival is earlier by more than the
error are head waves along the subcutaneous fat (n 3.45 against 7.9 in muscle), which ray
optics with a few interactions does not build. ~35 s (6 traces of 1e5 rays, 12 fields)."""

from __future__ import annotations

import numpy as np
import pytest

from evaluation.fields import organ_indices, voxel_grid
from evaluation.tracer_check import check_tracer
from raytrace.body.torso import BELT_SITES, UPPER_SITES, default_torso, expected_site_media
from raytrace.physics.tissues import dielectric

C = 299_792_458.0
EPS0 = 8.8541878128e-12


@pytest.fixture(scope="module")
def torso_check():
    phantom = default_torso()
    capsules = [n for n, s in phantom.sites.items() if s.kind == "capsule"]
    return check_tracer(phantom, capsules, [*BELT_SITES, *UPPER_SITES], 402e6)


@pytest.mark.slow
def test_no_traced_path_beats_the_eikonal_first_arrival(torso_check):
    chk = torso_check
    assert len(chk.pairs) == 72
    assert chk.error_s == pytest.approx(9.32 * 0.004 / C, rel=0.01)
    lines = [f"{p.capsule:18s} {p.sensor:22s} {p.verdict:16s} {p.difference_s * 1e12:8.0f} ps "
             f"{ {k: round(v, 2) for k, v in list(p.eikonal_media.items())[:3]} }" for p in chk.pairs
             if p.verdict != "agree"]
    print("\n".join(lines))
    assert not chk.by_verdict("no_path")
    assert not chk.by_verdict("traced_earlier"), lines
    diffs = np.array([p.difference_s for p in chk.pairs])
    assert diffs.min() >= -chk.error_s
    # where the tracer's fastest path is the global minimum the two agree within the error
    assert len(chk.by_verdict("agree")) >= 60


@pytest.mark.slow
def test_where_the_eikonal_is_earlier_its_ray_runs_along_the_fat(torso_check):
    early = torso_check.by_verdict("eikonal_earlier")
    assert early  # the torso has such pairs: contralateral sensors of the colon limbs and stomach
    for p in early:
        assert p.eikonal_media.get("subcutaneous_fat", 0.0) >= 0.5, (p.capsule, p.sensor, p.eikonal_media)


def test_voxel_grid_puts_every_capsule_site_in_its_organ():
    phantom = default_torso()
    grid = voxel_grid(phantom, 0.004)
    expected = expected_site_media()
    for name, site in phantom.sites.items():
        if site.kind != "capsule":
            continue
        cell = tuple(np.floor((site.position_m - grid.origin_m) / grid.spacing_m).astype(int))
        assert grid.organ_names[grid.organ[cell]] == expected[name]
    # outside the body is air; the grid's outermost cells are padding
    assert (grid.organ[0] == -1).all() and (grid.organ[:, :, -1] == -1).all()


def test_organ_indices_are_the_phase_index_at_the_carrier():
    # Re sqrt(eps' - j sigma / (w eps0)) from the tabulated permittivity and conductivity
    phantom = default_torso()
    n = organ_indices(phantom, 402e6, "phase")
    for organ, value in zip(phantom.organs, n):
        d = dielectric(organ.material.tissue, 402e6)
        eps = d.relative_permittivity - 1j * d.conductivity_s_per_m / (2 * np.pi * 402e6 * EPS0)
        assert value == pytest.approx(np.sqrt(eps).real, rel=1e-12)


def test_organ_indices_of_group_delays_are_the_group_index_and_the_default():
    """n_g = c d(Re k)/dw = d(w Re n)/dw, here by a central difference of w Re n(w) over +-1 MHz
    from the tabulated permittivity and conductivity (no derivative code of the project). The
    difference's truncation error is ~(df/f)^2 times the curvature: 1e-5 relative is generous."""
    phantom = default_torso()
    f, df = 402e6, 1e6

    def w_re_n(tissue, freq):
        d = dielectric(tissue, freq)
        eps = d.relative_permittivity - 1j * d.conductivity_s_per_m / (2 * np.pi * freq * EPS0)
        return 2 * np.pi * freq * np.sqrt(eps).real

    n_g = organ_indices(phantom, f, "group")
    np.testing.assert_array_equal(organ_indices(phantom, f), n_g)  # group: what a TOA receiver measures
    for organ, value in zip(phantom.organs, n_g):
        t = organ.material.tissue
        expected = (w_re_n(t, f + df) - w_re_n(t, f - df)) / (2 * np.pi * 2 * df)
        assert value == pytest.approx(expected, rel=1e-5)


def test_group_delays_of_direct_paths_match_the_eikonal_group_travel_time():
    """The eikonal solver on the GROUP index (docs/science.md (S22)) is an oracle for the
    tracer's ``group_delay_s`` sharing no code with it: on a homogeneous lossy, dispersive
    muscle sphere the direct path is the Fermat path, so its group delay must equal the
    first-arrival time of the group-index field within the grid's stated error."""
    import raytrace as rt
    from evaluation.fields import sensor_fields

    phantom = rt.get_phantom("homogeneous-sphere")
    capsule = phantom.sites["centre"].position_m
    sensors = np.array([[0.05, 0.02, -0.01], [-0.03, -0.06, 0.02], [0.0, 0.01, 0.07]])
    fields = sensor_fields(phantom, sensors, 402e6, cell_size_m=0.004, delay_kind="group")
    t_eik, _ = fields.evaluate(capsule)
    # far field: group_delay_s is the phase slope of the path's whole gain, and the dipole's near-field
    # factor (k r ~ 3.5 here) has a slope of its own (-110 ps) that no travel time carries
    spec = rt.ChannelSpec(rt.Antenna(capsule), tuple(rt.Antenna(s) for s in sensors), phantom=phantom.name,
                          max_interactions=1, rays=2000, near_field=False)
    result = rt.trace_channel(spec)
    for j, prof in enumerate(result.profiles):
        direct = prof.paths[0]
        assert direct.interactions == ()
        assert abs(direct.group_delay_s - float(t_eik[j])) <= fields.discretisation_error_s
        assert abs(direct.delay_s - float(t_eik[j])) > fields.discretisation_error_s  # the phase delay is not it
