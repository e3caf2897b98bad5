"""raytrace.body.indexgrid: the content hash that keys the travel-time fields on disk, and the index
per cell. Oracles: two independent builds of one phantom (equal hashes), a changed material or mesh
(different hashes), the per-organ indices written here (Re sqrt(eps_r*) of an explicit medium)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import trimesh

from raytrace.body.indexgrid import grid_key, index_grid, organ_indices, phantom_digest
from raytrace.body.phantom import Material, Organ, Phantom
from raytrace.errors import InputError

EPS0 = 8.8541878128e-12


def box(eps=27.9, sigma=0.5, extent=0.1):
    mesh = trimesh.creation.box(extents=(extent, extent, extent))
    return Phantom.build("box", [Organ("body", Material(relative_permittivity=eps, conductivity_s_per_m=sigma),
                                       mesh)])


def test_the_content_hash_is_the_content():
    a, b = box(), box()
    assert a is not b and phantom_digest(a) == phantom_digest(b)  # stable across builds (and processes)
    assert phantom_digest(box(eps=28.0)) != phantom_digest(a)  # a material
    assert phantom_digest(box(extent=0.1001)) != phantom_digest(a)  # the mesh
    renamed = dataclasses.replace(a, organs=(dataclasses.replace(a.organs[0], name="other"),))
    assert phantom_digest(renamed) != phantom_digest(a)
    key = grid_key(a, 402e6, 0.004, "group")
    assert key != grid_key(a, 402e6, 0.004, "phase") != grid_key(a, 403e6, 0.004, "phase")
    assert grid_key(a, 402e6, 0.004, "phase") != grid_key(a, 402e6, 0.005, "phase")
    with pytest.raises(InputError) as info:
        grid_key(a, 402e6, 0.004, "envelope")
    assert info.value.field == "delay_kind"


def test_index_per_cell_is_the_organs_index_and_air_is_nan():
    phantom = box()
    f = 402e6
    n_phase = np.sqrt(27.9 - 1j * 0.5 / (2 * np.pi * f * EPS0)).real
    assert organ_indices(phantom, f, "phase") == pytest.approx([n_phase], rel=1e-12)
    # an explicit medium: eps' constant, so d(w Re n)/dw comes from the conductivity term alone, and
    # Re n > n_g (the loss term falls with frequency): checked against a central difference
    w_re_n = [2 * np.pi * g * np.sqrt(27.9 - 1j * 0.5 / (2 * np.pi * g * EPS0)).real for g in (f - 1e6, f + 1e6)]
    n_group = (w_re_n[1] - w_re_n[0]) / (2 * np.pi * 2e6)
    assert organ_indices(phantom, f, "group") == pytest.approx([n_group], rel=1e-5)
    grid, n = index_grid(phantom, f, 0.01, "phase")
    assert n.shape == grid.shape
    assert np.isnan(n[0]).all() and np.isnan(n[:, :, -1]).all()  # the padding is air
    inside = grid.organ >= 0
    assert inside.any() and np.allclose(n[inside], n_phase, rtol=1e-12)
