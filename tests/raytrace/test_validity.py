"""Where geometric optics stops (raytrace.spec ChannelSpec.resolve, raytrace.solver.validity;
docs/science.md section 8): frequencies whose wavelength in the transmitter's tissue exceeds the
phantom are refused naming the field and the valid range; every profile reports the electrical
size of the smallest organ it crossed. Oracles: numpy's square root of the Gabriel permittivity
and the organs' principal extents computed here."""

from __future__ import annotations

import dataclasses
import re

import numpy as np
import pytest

import raytrace as rt
from raytrace.errors import FrequencyOutOfRangeError
from raytrace.physics import tissues

C = 299_792_458.0


def _wavelength(tissue, f):
    n = np.sqrt(tissues.complex_relative_permittivity(tissue, f))
    return C / (f * abs(n.real))


def _spec(**kw):
    return rt.ChannelSpec(rt.Antenna(site="small_intestine_1"), [rt.Antenna(site="belt_anterior")], rays=2000, **kw)


@pytest.mark.parametrize("frequency_hz", [402.0, 10e3])
def test_a_frequency_below_geometric_optics_is_refused_naming_the_field_and_the_range(frequency_hz):
    # 402 Hz (MHz typed as Hz): the wavelength in the small intestine is ~200 m, against a 0.67 m torso
    torso = rt.get_phantom("torso")
    with pytest.raises(FrequencyOutOfRangeError) as exc:
        _spec(frequency_hz=frequency_hz).resolve(torso)
    assert exc.value.field == "frequency_hz"
    low = float(re.search(r"valid range for this transmitter is ([0-9.e+]+)-", exc.value.reason).group(1))
    # the stated lower limit is where the small intestine's wavelength equals the torso's size, its
    # bounding-box diagonal (0.2 %: the message's four digits)
    size = float(np.linalg.norm(torso.bounds_m[1] - torso.bounds_m[0]))
    assert _wavelength("small_intestine", low) == pytest.approx(size, rel=2e-3)
    _spec(frequency_hz=low * 1.01).resolve(torso)  # just above it: accepted


def test_band_frequencies_are_checked_too():
    torso = rt.get_phantom("torso")
    with pytest.raises(FrequencyOutOfRangeError) as exc:
        _spec(band=rt.Band(1e3, 420e6, 5)).resolve(torso)
    assert exc.value.field == "band.start_hz"
    with pytest.raises(FrequencyOutOfRangeError) as exc:
        _spec(band=rt.Band(frequencies_hz=[402e6, 5e6])).resolve(torso)
    assert exc.value.field == "band.frequencies_hz[1]"


def _width(phantom, organ):
    v = np.asarray(phantom.organs[phantom.organ_index(organ)].mesh.vertices)
    v = v - v.mean(axis=0)
    axes = np.linalg.eigh(v.T @ v)[1]  # principal axes (covariance eigenvectors)
    extents = np.ptp(v @ axes, axis=0)
    return float(np.sort(extents)[1])  # the middle one: the organ's width


@pytest.mark.parametrize("frequency_hz, warned", [(402e6, True), (2.45e9, False)])
def test_profiles_report_their_smallest_organ_in_wavelengths(frequency_hz, warned):
    # At 402 MHz the torso's colon segments and spine are below a wavelength wide; at 2.45 GHz
    # every organ crossed from small_intestine_1 to belt_anterior is over one wavelength.
    torso = rt.get_phantom("torso")
    spec = dataclasses.replace(_spec(frequency_hz=frequency_hz), rays=20_000)
    prof = rt.trace_channel(spec).profiles[0]
    crossed = {s.medium for p in prof.paths for s in p.segments} - {"air"}
    sizes = {o: _width(torso, o) / _wavelength(torso.organs[torso.organ_index(o)].material.tissue, frequency_hz)
             for o in crossed}
    smallest = min(sizes, key=sizes.get)
    assert prof.smallest_organ == smallest
    assert prof.smallest_organ_size_wavelengths == pytest.approx(sizes[smallest], rel=1e-9)
    assert (len(prof.warnings) == 1) == warned == (sizes[smallest] < 1.0)
    if warned:
        assert smallest in prof.warnings[0] and "wavelength" in prof.warnings[0]
