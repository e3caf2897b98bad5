"""Position estimators: the capsule's position from several sensors' ranges, delays or path
losses, with position Cramér-Rao bounds (docs/localization.md). Pure functions: no tracer,
no service.

    linear_fix(sensors_m, ranges_m, sigma_m=None)                    closed form (starts the others)
    nonlinear_fix(sensors_m, ranges_m, sigma_m=None, loss="linear")  weighted NLS on ranges
    joint_velocity_fix(sensors_m, delays_s, sigma_s=None)            position + effective velocity (>= 5)
    rss_fix(sensors_m, path_loss_db, model="cm2_deep_tissue")        path-loss inversion + multilateration
    model_based_fix(fields, delays_s, sigma_s=None)                  travel-time fields (heterogeneity-aware)
        (fields built with the index of the delays' kind: DELAY_KINDS, measured_delay_kind(ranging))
        -> PositionResult(position_m, covariance_m2, residuals_m, iterations, converged, bound, ...)
    METHODS / locate(name, Measurements(...))                       the one registry of these methods: what each
        measures and its fix (estimators.localization.methods); the service, the evaluation and the sweeps use it

    travel_time_field / cached_travel_time_field(index, origin_m, spacing_m, sensor_position_m)
        -> TravelTimeField (eikonal, scikit-fmm); TravelTimeFields(fields) interpolates T_i and grad T_i
    range_crlb / joint_velocity_crlb / travel_time_crlb / rss_position_crlb -> PositionBound(covariance_m2,
        sigma_m, rms_m, gdop, pdop)

Errors: EstimatorInputError naming the field (``sensors``, ``ranges_m``, ``sigma_m``, ...).
"""

from .bounds import joint_velocity_crlb, range_crlb, rss_position_crlb, travel_time_crlb
from .delays import DEFAULT_DELAY_KIND, DELAY_KINDS, check_delay_kind, measured_delay_kind
from .methods import METHODS, POSITION_METHODS, Measurements, Method, locate, position_method
from .model_based import model_based_fix
from .multilateration import joint_velocity_fix, linear_fix, nonlinear_fix
from .pathloss import fit_path_loss_model, path_loss_model, rss_fix
from .results import PositionBound, PositionResult
from .traveltime import (
                         TravelTimeField,
                         TravelTimeFields,
                         cached_travel_time_field,
                         clear_cache,
                         travel_time_field,
)

__all__ = [
    "DEFAULT_DELAY_KIND", "DELAY_KINDS", "METHODS", "Measurements", "Method", "POSITION_METHODS",
    "PositionBound", "PositionResult", "TravelTimeField", "TravelTimeFields",
    "cached_travel_time_field", "check_delay_kind", "clear_cache", "fit_path_loss_model", "joint_velocity_crlb",
    "joint_velocity_fix", "linear_fix", "measured_delay_kind", "model_based_fix", "nonlinear_fix", "path_loss_model",
    "locate", "position_method", "range_crlb", "rss_fix", "rss_position_crlb", "travel_time_crlb", "travel_time_field",
]
