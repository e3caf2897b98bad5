"""The one registry of position methods (estimators.localization.methods): every method fixes a capsule
from exact, noiseless measurements of a known geometry (the oracle: the distances written here, |s - x|),
says what it measures, and the API's and the evaluation's method lists are the registry's."""

from __future__ import annotations

import numpy as np
import pytest

from estimators.constants import velocity_m_per_s
from estimators.errors import EstimatorInputError
from estimators.localization import METHODS, POSITION_METHODS, Measurements, locate, position_method
from estimators.rss import CM2_MODELS

TRUE_M = np.array([0.01, -0.02, 0.03])
SENSORS_M = np.array([[0.15, 0.0, 0.0], [-0.15, 0.02, 0.0], [0.0, 0.15, 0.01], [0.02, -0.15, 0.0],
                      [0.0, 0.01, 0.15], [0.01, 0.0, -0.15]])
#: Noiseless inputs: a fix lands on the truth to the solver's tolerance (1 um is far above it, far below
#: any sensor spacing).
TOL_M = 1e-6


def _exact(measures: str) -> Measurements:
    d = np.linalg.norm(SENSORS_M - TRUE_M, axis=1)
    model = CM2_MODELS["cm2_deep_tissue"]
    return Measurements(sensors_m=SENSORS_M, ranges_m=d, delays_s=d / velocity_m_per_s(),
                        path_loss_db=model.path_loss_db(d), model=model)


@pytest.mark.parametrize("name", [m for m in POSITION_METHODS if not METHODS[m].needs_fields])
def test_each_method_fixes_exact_measurements(name):
    fix = locate(name, _exact(METHODS[name].measures))
    assert fix.method == name
    assert np.linalg.norm(fix.position_m - TRUE_M) < TOL_M


def test_the_registry_says_what_each_method_measures_and_refuses_what_it_lacks():
    assert {m: METHODS[m].measures for m in POSITION_METHODS} == {
        "linear": "ranges_m", "nonlinear": "ranges_m", "joint_velocity": "delays_s", "model_based": "delays_s",
        "rss": "path_loss_db"}
    with pytest.raises(EstimatorInputError) as err:
        locate("joint_velocity", Measurements(sensors_m=SENSORS_M, ranges_m=np.ones(6)))
    assert err.value.field == "delays_s"
    with pytest.raises(EstimatorInputError) as err:
        locate("model_based", Measurements(delays_s=np.ones(6)))
    assert err.value.field == "fields"
    with pytest.raises(EstimatorInputError) as err:
        position_method("trilateration", "methods[2]")
    assert err.value.field == "methods[2]"


def test_the_api_and_the_evaluation_offer_the_registrys_methods():
    from evaluation.localization import DELAY_METHODS
    from service.schemas.localize import LocalizeRequest

    assert tuple(LocalizeRequest.model_json_schema()["properties"]["method"]["enum"]) == POSITION_METHODS
    assert DELAY_METHODS == ("linear", "nonlinear", "joint_velocity", "model_based")
