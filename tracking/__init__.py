"""Tracking the capsule along the GI tract: a seeded journey, a Kalman filter and a particle filter on
the centreline fusing RF position fixes with visual odometry (docs/tracking.md).

Pure: imports raytrace's centreline (through the caller's object) and numpy/scipy, never the service.
"""

from .errors import TrackingInputError
from .journey import Journey, JourneySpec, simulate_journey
from .kalman import kalman_track
from .measurements import Observation, RfFix, Track, TrackerConfig, VisualMotion
from .metrics import ConsistencyBand, average_band, integrated_autocorrelation, nees, rmse_3d_m, rmse_along_m
from .particle import particle_track


def _kalman(line, observations, config=None, *, name: str = "kalman", check=None):
    return kalman_track(line, observations, config, name=name)  # linear in the steps: nothing to check


#: The trackers, one registry: name -> ``track(line, observations, config, *, name, check=None)`` (``check``
#: is called between steps by those whose work it bounds). POST /v1/track's ``tracker`` and the journey
#: evaluation's filters (docs/tracking.md) are looked up here.
TRACKERS = {"kalman": _kalman, "particle": particle_track}

__all__ = ["TRACKERS", "ConsistencyBand", "Journey", "JourneySpec", "Observation", "RfFix", "Track", "TrackerConfig",
           "TrackingInputError", "VisualMotion", "average_band", "integrated_autocorrelation", "kalman_track", "nees",
           "particle_track", "rmse_3d_m", "rmse_along_m", "simulate_journey"]
