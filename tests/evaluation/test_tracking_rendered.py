"""The tracking evaluation with visual motion from frames rendered along the journey
(evaluation.tracking, visual_source="rendered"; vision.odometry).

Oracle: the journey's own arc lengths and rolls (tracking.simulate_journey), which the renderer
turns into poses; the estimator never sees them."""

from __future__ import annotations

import numpy as np
import pytest

from evaluation.tracking import evaluate_tracking
from raytrace.body.torso import default_torso
from tracking import JourneySpec, TrackingInputError, simulate_journey
from vision.errors import VisionInputError
from vision.odometry import OdometrySettings, pair_estimates


@pytest.fixture(scope="module")
def torso():
    return default_torso()


def test_rendered_pairs_follow_the_journey_and_are_cached(torso, tmp_path):
    """20 steps from s = 0.345 m in the ascending colon (128 px frames to keep it short). Measured
    on these pairs: advance errors <= 0.09 mm, roll errors <= 0.39 deg (128 px is coarse for roll);
    tolerances 0.2 mm and 0.8 deg. A second call reads every pair from the cache: identical."""
    line = torso.centrelines["gi_tract"]
    j = simulate_journey(line, JourneySpec(steps=20, seed=3, start_m=0.345))
    settings = OdometrySettings(size_px=128)
    first = pair_estimates(torso, j.s_m, j.roll_deg, settings, cache_dir=tmp_path)
    assert first[0] is None and all(p is not None for p in first[1:])
    for k in range(1, 20):
        assert first[k].advance_m == pytest.approx(j.s_m[k] - j.s_m[k - 1], abs=2e-4)
        assert first[k].rotation_deg == pytest.approx(j.roll_deg[k] - j.roll_deg[k - 1], abs=0.8)
    again = pair_estimates(torso, j.s_m, j.roll_deg, settings, cache_dir=tmp_path)
    assert again == first


def test_scene_cut_gives_no_pair(torso):
    """Frames on two sides of an organ junction are not a pair."""
    cut = float(torso.centrelines["gi_tract"].junctions_s_m[1])
    out = pair_estimates(torso, [cut - 1e-3, cut + 1e-3], [0.0, 1.0], OdometrySettings(size_px=64))
    assert out == [None, None]


def test_bad_input_names_the_field(torso):
    with pytest.raises(VisionInputError) as e:
        pair_estimates(torso, [0.2, 5.0], [0.0, 0.0], OdometrySettings(size_px=64))
    assert e.value.field == "s_m[1]"
    with pytest.raises(TrackingInputError) as e:
        evaluate_tracking(JourneySpec(steps=5), ("video",), visual_source="frames")
    assert e.value.field == "visual_source"


def test_video_only_track_from_rendered_frames(torso, tmp_path):
    """The video-only Kalman filter on 20 rendered steps in the ascending colon (192 px, 16.9 mm
    travelled): the distance travelled within 1 mm of the truth (measured 0.46 mm: the pairs'
    advance errors, -0.03 mm each on average, add up)."""
    ev = evaluate_tracking(JourneySpec(steps=20, seed=3, start_m=0.345), ("video",), phantom=torso,
                           visual_source="rendered", cache_dir=tmp_path)
    track, truth = ev.tracks["video"], ev.journey
    travelled = track.s_m[-1] - track.s_m[0]
    assert travelled == pytest.approx(truth.s_m[-1] - truth.s_m[0], abs=1e-3)
    assert ev.visual_pairs == 19
    assert np.isfinite(ev.rmse_along_m["video"])
