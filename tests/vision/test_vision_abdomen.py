"""Frames rendered along the CT abdomen's journey are images of its real lumen, and the MI motion estimator
(with the fisheye's tilt, as the tracking evaluation runs it) recovers their motion within its stated error.

Oracles: the renderer's exact per-pixel geometry (a frame of the real lumen sees its walls a few millimetres
to centimetres away, all of them the organ the centreline names), the torso's frame at the same arc length
(another phantom: the frames must differ), and the journey's truth (advances and rolls drawn here). The
stated error is what the filters are told for rendered frames (evaluation.tracking: small bowel 15 % of the
advance + 0.1 mm and 0.5 deg; colon 6 % + 0.03 mm), asserted at 3 sigma for 5 of 6 pairs per organ (a
fold-aliased pair is an outlier the filters gate) and every roll within 0.5 deg."""

from __future__ import annotations

import numpy as np
import pytest

from raytrace.body.abdomen import abdomen_ct
from raytrace.body.torso import default_torso
from vision.camera import FisheyeCamera
from vision.mucosa import texture_for
from vision.odometry import OdometrySettings, pair_estimates
from vision.render import render_frame
from vision.sequence import centreline_pose

#: (declared relative, absolute [m]) per mucosa: evaluation.tracking's RENDERED_DECLARED (docs/tracking.md)
DECLARED = {"small_intestine": (0.15, 1e-4), "colon": (0.06, 3e-5)}


def _frame(phantom, s_m: float):
    pose, organ = centreline_pose(phantom, s_m)
    return render_frame(phantom, pose, FisheyeCamera(150.0, 128), texture=texture_for(organ, phantom=phantom),
                        organ=organ)


def test_frames_are_of_the_real_lumen_not_the_torso_s() -> None:
    abdomen, torso = abdomen_ct(), default_torso()
    for s_m in (0.25, 1.0, 3.3):  # the stomach's end, the jejunum, the transverse colon
        frame = _frame(abdomen, s_m)
        organ = abdomen.centrelines["gi_tract"].organ_at(s_m)
        # every pixel of the image circle (pi / 4 of the frame) sees the wall of that organ
        assert frame.mask.mean() > 0.78 and set(frame.organ[frame.mask].tolist()) == {abdomen.organ_index(organ)}
        depth = frame.depth_m[frame.mask]
        assert 0.5e-3 < depth.min() and np.median(depth) < 0.05  # inside a lumen: walls mm to cm away
        other = _frame(torso, s_m * torso.centrelines["gi_tract"].length_m / abdomen.centrelines["gi_tract"].length_m)
        both = frame.mask & other.mask
        difference = np.abs(frame.grey()[both] - other.grey()[both]).mean()
        assert difference > 0.05 * (frame.grey().max() - frame.grey().min()), difference


@pytest.mark.slow
@pytest.mark.parametrize("s0, mucosa", [(1.0, "small_intestine"), (3.8, "colon")])  # jejunum, descending colon
def test_the_mi_estimator_recovers_the_motion_within_its_stated_error(s0, mucosa) -> None:
    rng = np.random.default_rng(3)
    advance = rng.uniform(0.5e-3, 1.5e-3, 6)
    roll = np.concatenate([[0.0], np.cumsum(rng.uniform(-4.0, 4.0, 6))])
    s = np.concatenate([[s0], s0 + np.cumsum(advance)])
    pairs = pair_estimates(abdomen_ct(), s, roll, OdometrySettings())[1:]
    error = np.array([p.advance_m for p in pairs]) - advance
    rel, absolute = DECLARED[mucosa]
    within = np.abs(error) <= 3 * (rel * advance + absolute)
    assert within.sum() >= 5, (error / advance).round(3)
    roll_error = np.array([p.rotation_deg for p in pairs]) - np.diff(roll)
    assert np.all(np.abs(roll_error) <= 0.5), roll_error.round(3)
