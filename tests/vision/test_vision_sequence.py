"""Sequences along a path (ground truth of advance and roll) and the scale -> advance conversion."""

from __future__ import annotations

import math

import numpy as np
import pytest
import trimesh

from raytrace import Material, Organ, Phantom, default_torso
from vision.advance import advance_for_scale, scale_for_advance
from vision.camera import FisheyeCamera, Pose
from vision.errors import VisionInputError
from vision.motion import estimate_motion
from vision.mucosa import MucosaTexture
from vision.render import Lighting, render_frame
from vision.sequence import Path, render_sequence, sequence_poses


def test_straight_path_poses_advance_and_roll_exactly() -> None:
    path = Path([[0.0, 0.0, 0.0], [0.0, 0.0, 0.05]])
    truth = sequence_poses(path, 5, [0.001, 0.002, 0.0015, 0.001], 3.0, start_m=0.01, start_roll_deg=10.0)
    np.testing.assert_allclose(truth.s_m, [0.01, 0.011, 0.013, 0.0145, 0.0155])
    np.testing.assert_allclose(truth.roll_deg, [10, 13, 16, 19, 22])
    for pose, s in zip(truth.poses, truth.s_m):
        np.testing.assert_allclose(pose.position_m, [0, 0, s], atol=1e-15)
    # consecutive up vectors differ by exactly the 3 deg roll about the (fixed) view direction
    ups = np.array([p.basis[1] for p in truth.poses])
    angles = np.degrees(np.arccos(np.clip(np.einsum("ij,ij->i", ups[:-1], ups[1:]), -1, 1)))
    np.testing.assert_allclose(angles, 3.0, atol=1e-9)


def test_a_bend_adds_no_roll_parallel_transport() -> None:
    """Along x, then a right-angle bend to z, no roll requested: the up vector (initially +z,
    perpendicular to x) is carried across the bend by the smallest rotation taking x to z, i.e.
    90 deg about x cross z = -y, which takes +z to -x."""
    path = Path([[0.0, 0.0, 0.0], [0.01, 0.0, 0.0], [0.01, 0.0, 0.01]])
    truth = sequence_poses(path, 3, 0.009, 0.0, start_m=0.0015)
    np.testing.assert_allclose(truth.poses[0].basis[1], [0, 0, 1], atol=1e-12)
    np.testing.assert_allclose(truth.poses[1].basis[2], [0, 0, 1], atol=1e-12)
    np.testing.assert_allclose(truth.poses[1].basis[1], [-1, 0, 0], atol=1e-12)


def test_sequence_inputs_are_checked() -> None:
    path = Path([[0.0, 0.0, 0.0], [0.0, 0.0, 0.01]])
    for kwargs, field in ((dict(frames=0, advance_m=0.001, roll_deg=0), "frames"),
                          (dict(frames=3, advance_m=[0.001], roll_deg=0), "advance_m"),
                          (dict(frames=3, advance_m=0.006, roll_deg=0), "advance_m"),
                          (dict(frames=3, advance_m=0.001, roll_deg=[1, np.nan]), "roll_deg")):
        with pytest.raises(VisionInputError) as e:
            sequence_poses(path, **kwargs)
        assert e.value.field == field
    with pytest.raises(VisionInputError) as e:
        Path([[0, 0, 0], [0, 0, 0]])
    assert e.value.field == "path.points_m"


def test_scale_of_an_advance_towards_a_wall_is_the_pinhole_magnification() -> None:
    """Facing a flat wall at distance Z, advancing by d magnifies a pinhole image by Z / (Z - d);
    a narrow (10 deg) fisheye is a pinhole to O(theta^2): the ratio atan(rho / (Z - d)) /
    atan(rho / Z) departs from Z / (Z - d) by the cubic term of atan, at most
    s tan^2(5 deg) (s^2 - 1) / 3 = 7e-4 at the rim (s = 1.11), less on average: tolerance 1e-3.
    The conversion is the inverse of s(d) (round trip to 1e-9 m)."""
    half = 0.1
    phantom = Phantom.build("box", [Organ("box", Material(relative_permittivity=2.0),
                                          trimesh.creation.box(extents=(2 * half,) * 3))])
    z, d = 0.02, 0.002
    frame = render_frame(phantom, Pose([0.0, 0.0, half - z], [0, 0, 1]), FisheyeCamera(10.0, 64),
                         lighting=Lighting(specular=0.0), exposure=1.0)
    assert scale_for_advance(frame, d) == pytest.approx(z / (z - d), abs=1e-3)
    assert scale_for_advance(frame, -d) == pytest.approx(z / (z + d), abs=1e-3)
    assert advance_for_scale(frame, scale_for_advance(frame, d)) == pytest.approx(d, abs=1e-9)
    with pytest.raises(VisionInputError) as e:
        advance_for_scale(frame, 50.0)
    assert e.value.field == "scale"


def test_roll_and_advance_of_a_rendered_colon_sequence_are_recovered() -> None:
    """Real (rendered) motion, not synthetic warps: the capsule advances 1.5 mm and rolls 4 deg
    per frame along the ascending colon's axis (192 px frames). The estimated rotation is the
    roll increment within 0.15 deg (measured <= 0.07: looking down a tube with circular folds
    the frame is nearly symmetric under roll; only vessels and the folds' wander show it), and
    the scale converted through the rendered geometry gives the advance within 10 % (measured
    -3 to -7 %: an advance is not exactly a similarity; docs/vision.md, Evaluation)."""
    torso = default_torso()
    c = torso.sites["ascending_colon"].position_m
    path = Path([c - [0, 0, 0.02], c + [0, 0, 0.02]])
    seq = render_sequence(torso, path, 3, 0.0015, 4.0, FisheyeCamera(150.0, 192),
                          texture=MucosaTexture.colon(fold_axis=(0, 0, 1)), organ="ascending_colon")
    for a, b in zip(seq.frames[:-1], seq.frames[1:]):
        est = estimate_motion(a.grey(), b.grey())
        assert abs(est.rotation_deg - 4.0) <= 0.15, est
        assert advance_for_scale(a, est.scale) == pytest.approx(0.0015, rel=0.10), est
    assert math.isclose(seq.truth.s_m[-1] - seq.truth.s_m[0], 0.003)
