"""ChannelSpec and Antenna rules that are not about a phantom (raytrace/spec.py)."""

from __future__ import annotations

import numpy as np
import pytest

from raytrace.errors import InvalidGeometryError
from raytrace.spec import Antenna


@pytest.mark.parametrize("given, unit", [
    ((1e200, 1e200, 0.0), (2**-0.5, 2**-0.5, 0.0)),  # |p| overflows a float
    ((0.0, 0.0, 1e-320), (0.0, 0.0, 1.0)),  # |p|^2 underflows to 0
    ((0.0, -3.0, 4.0), (0.0, -0.6, 0.8)),
])
def test_any_finite_non_zero_polarization_is_normalised(given, unit):
    """The unit vector p / |p|, written out by hand for each case (tolerance: float64 rounding)."""
    a = Antenna(site="belt_left", polarization=given)
    np.testing.assert_allclose(a.polarization, unit, rtol=0, atol=1e-15)
    # and it stays valid when the antenna is rebuilt with a position (sites resolve this way)
    np.testing.assert_allclose(Antenna((0.1, 0.0, 0.0), polarization=a.polarization).polarization, unit, atol=1e-15)


def test_a_zero_polarization_is_refused_naming_the_field():
    with pytest.raises(InvalidGeometryError) as info:
        Antenna(site="belt_left", polarization=(0.0, 0.0, 0.0))
    assert info.value.field == "polarization"
