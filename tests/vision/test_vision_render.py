"""The capsule camera renderer against closed forms: ray distances in a box and a tube built with
trimesh primitives, the LED fall-off on a flat plate, the roll convention, the sensor."""

from __future__ import annotations

import math

import numpy as np
import pytest
import trimesh

from raytrace import Material, Organ, Phantom, default_torso
from vision.camera import FisheyeCamera, Pose
from vision.errors import VisionInputError
from vision.mucosa import MucosaTexture
from vision.render import Lighting, render_frame
from vision.sensor import SensorModel

LINEAR = SensorModel(vignetting=0.0, gamma=None, quantize_8bit=False)


def one_organ(mesh: trimesh.Trimesh, name: str = "lumen") -> Phantom:
    return Phantom.build(name, [Organ(name, Material(relative_permittivity=2.0), mesh)])


def expected_rays(size: int, fov_deg: float, forward, roll_deg: float, hint=(0.0, 0.0, 1.0)):
    """The test's own fisheye: pixel (row, col) -> theta = r / f with f = (size / 2) / (fov / 2),
    r from the frame centre, x right, y up; the camera basis from the view direction, the up hint
    made perpendicular and turned by the roll (right-hand rule about the view direction), right =
    forward x up (the documented hint for a camera looking along z is -y). Returns (unit
    directions (S, S, 3) in the phantom frame, theta (S, S))."""
    c = (size - 1) / 2
    rows, cols = np.mgrid[0:size, 0:size].astype(float)
    x, y = cols - c, c - rows
    theta = np.hypot(x, y) / ((size / 2) / math.radians(fov_deg / 2))
    phi = np.arctan2(y, x)
    f = np.asarray(forward, float) / np.linalg.norm(forward)
    up = np.asarray(hint, float) - np.dot(hint, f) * f
    up /= np.linalg.norm(up)
    a = math.radians(roll_deg)
    up = up * math.cos(a) + np.cross(f, up) * math.sin(a)  # f is perpendicular to up
    right = np.cross(f, up)
    d = (np.sin(theta) * np.cos(phi))[..., None] * right + (np.sin(theta) * np.sin(phi))[..., None] * up \
        + np.cos(theta)[..., None] * f
    return d, theta


class PlateTexture:
    """A checkerboard of reflectances 0.3 / 0.9 in 4 mm squares (x, y), normals untouched."""

    @staticmethod
    def albedo(points: np.ndarray) -> np.ndarray:
        parity = (np.floor(points[:, 0] / 4e-3) + np.floor(points[:, 1] / 4e-3)) % 2
        return np.repeat(np.where(parity == 0, 0.3, 0.9)[:, None], 3, axis=1)

    def shade_inputs(self, points, normals):
        return self.albedo(points), normals


def test_every_pixel_hits_the_box_wall_at_the_closed_form_distance() -> None:
    """Camera off-centre in a 40 x 50 x 60 mm box, looking obliquely, rolled: each pixel's
    distance is min over the six planes of (+-half extent - p) / d along its ray (written here).
    The renderer re-intersects Embree's triangle in float64: within 1e-9 m, except rays
    grazing a box edge where Embree's float32 may pick the other face's triangle (its plane
    meets the ray within float32 rounding of the edge: 1e-6 m), at most 0.1 % of the pixels."""
    half = np.array([0.020, 0.025, 0.030])
    phantom = one_organ(trimesh.creation.box(extents=2 * half))
    p0, forward, roll = np.array([0.004, -0.006, 0.003]), np.array([0.3, 0.5, 0.8]), 17.0
    cam = FisheyeCamera(160.0, 96)
    frame = render_frame(phantom, Pose(p0, forward, roll), cam, sensor=LINEAR, exposure=1.0)
    d, theta = expected_rays(96, 160.0, forward, roll)
    inside = theta <= math.radians(80.0)
    with np.errstate(divide="ignore"):
        t = np.where(d > 0, (half - p0) / d, (-half - p0) / d)
    expected = np.min(np.where(np.isfinite(t) & (t > 0), t, np.inf), axis=-1)
    assert np.array_equal(frame.mask, inside)
    err = np.abs(frame.depth_m[inside] - expected[inside])
    assert err.max() < 1e-6 and np.mean(err > 1e-9) < 1e-3
    np.testing.assert_allclose(frame.points_m[inside], (p0 + expected[..., None] * d)[inside], atol=1e-6)


def test_the_tube_wall_and_its_end_cap_are_where_the_closed_form_puts_them() -> None:
    """Camera on the axis of a tube (radius 12.5 mm, 512-sided, capped at z = +-50 mm), 30 mm
    below the top cap, looking up the axis: a ray at theta from the axis meets the side at
    R / sin(theta) or the cap at 20 mm / cos(theta), whichever is nearer. The side is a polygon
    inscribed in the circle: its distance lies within R (1 - cos(pi / 512)) / sin(theta) (the
    sagitta) inside the circle's; the flat cap is exact (1e-9 m)."""
    r, n = 0.0125, 512
    phantom = one_organ(trimesh.creation.cylinder(radius=r, height=0.1, sections=n))
    frame = render_frame(phantom, Pose([0.0, 0.0, 0.03], [0.0, 0.0, 1.0]), FisheyeCamera(150.0, 80),
                         sensor=LINEAR, exposure=1.0)
    _, theta = expected_rays(80, 150.0, [0, 0, 1], 0.0, hint=(0.0, -1.0, 0.0))
    m = frame.mask
    with np.errstate(divide="ignore"):
        side, cap = r / np.sin(theta), 0.02 / np.cos(theta)
    on_cap = cap < side * math.cos(math.pi / n) - 1e-6
    on_side = side < cap - 1e-6
    assert (m & on_cap).sum() > 100 and (m & on_side).sum() > 1000
    np.testing.assert_allclose(frame.depth_m[m & on_cap], cap[m & on_cap], atol=1e-9)
    gap = frame.depth_m[m & on_side] - side[m & on_side]
    sagitta = r * (1 - math.cos(math.pi / n)) / np.sin(theta[m & on_side])
    assert np.all(gap <= 1e-9) and np.all(gap >= -sagitta - 1e-9)


@pytest.mark.parametrize("exponent", [0.0, 1.0])
def test_a_flat_plate_falls_off_as_the_inverse_square_and_lambert_laws(exponent) -> None:
    """One LED at the lens (ring radius 0) of intensity I with emission pattern cos^m, a
    Lambertian plate of reflectance rho(P) at distance D perpendicular to the axis: a pixel at
    theta sees P at D / cos(theta), lit at incidence theta, so its linear value is
    I rho(P) / pi * cos^m(theta) cos(theta) / (D / cos(theta))^2 = I rho / (pi D^2) cos^(3+m)
    (theta). The checkerboard texture makes rho vary across the plate; exact to 1e-9."""
    half = 0.1
    phantom = one_organ(trimesh.creation.box(extents=(2 * half, 2 * half, 2 * half)))
    dist, intensity = 0.02, 3e-4
    light = Lighting(led_count=1, ring_radius_m=0.0, intensity=intensity, emission_exponent=exponent, specular=0.0)
    cam = FisheyeCamera(120.0, 65)
    frame = render_frame(phantom, Pose([0.0, 0.0, half - dist], [0, 0, 1]), cam, lighting=light,
                         texture=PlateTexture(), sensor=LINEAR, exposure=1.0)
    d, theta = expected_rays(65, 120.0, [0, 0, 1], 0.0, hint=(0.0, -1.0, 0.0))
    plate = frame.mask & (np.abs(frame.points_m[..., 2] - half) < 1e-9)
    assert plate.sum() == frame.mask.sum()  # the 60 deg half-angle cone stays on the plate
    points = np.array([0.0, 0.0, half - dist]) + (dist / np.cos(theta))[..., None] * d
    rho = PlateTexture.albedo(points[plate])[:, 0]
    expected = intensity * rho / (math.pi * dist**2) * np.cos(theta[plate]) ** (3 + exponent)
    for channel in range(3):
        np.testing.assert_allclose(frame.linear[..., channel][plate], expected, rtol=1e-9)


def test_inverse_square_and_the_specular_lobe_on_the_axis() -> None:
    """The centre pixel of an odd frame looks along the axis at the plate, where the normal, the
    light and the view coincide: n . h = 1, so its value is I / D^2 (rho / pi + k_s (s + 8) /
    (8 pi)) -- and 4x smaller at twice the distance."""
    half = 0.1
    phantom = one_organ(trimesh.creation.box(extents=(2 * half,) * 3))
    light = Lighting(led_count=1, ring_radius_m=0.0, intensity=1e-4, emission_exponent=1.0, specular=0.4,
                     shininess=20.0)
    values = []
    for dist in (0.01, 0.02):
        frame = render_frame(phantom, Pose([0.0, 0.0, half - dist], [0, 0, 1]), FisheyeCamera(90.0, 33),
                             lighting=light, texture=PlateTexture(), sensor=LINEAR, exposure=1.0)
        values.append(frame.linear[16, 16, 0])
    rho = PlateTexture.albedo(np.zeros((1, 3)))[0, 0]
    assert values[0] == pytest.approx(1e-4 / 0.01**2 * (rho / math.pi + 0.4 * 28.0 / (8 * math.pi)), rel=1e-9)
    assert values[0] / values[1] == pytest.approx(4.0, rel=1e-9)


@pytest.fixture(scope="module")
def torso():
    return default_torso()


def test_a_positive_roll_turns_the_frame_counter_clockwise(torso) -> None:
    """Rolling the camera by +90 deg about its view direction (right-hand rule) makes it see the
    same rays, each at the pixel a quarter turn counter-clockwise (the 4-LED ring maps onto
    itself): the frame must equal np.rot90 of the unrolled one. This fixes the sign shared with
    the motion estimator: rotation_deg = +roll increment. Rays grazing a mesh edge may pick the
    neighbouring triangle in float32 (tolerance on at most 0.2 % of pixels)."""
    c = torso.sites["ascending_colon"].position_m
    tex = MucosaTexture.colon(fold_axis=(0, 0, 1))
    kw = dict(texture=tex, sensor=LINEAR, exposure=1.0, organ="ascending_colon")
    cam = FisheyeCamera(150.0, 64)
    a = render_frame(torso, Pose(c, [0.2, 0.1, 1.0], 0.0), cam, **kw).linear
    b = render_frame(torso, Pose(c, [0.2, 0.1, 1.0], 90.0), cam, **kw).linear
    close = np.isclose(b, np.rot90(a), rtol=1e-6, atol=1e-9).all(axis=-1)
    assert close.mean() > 0.998


def test_the_compiled_wall_hits_match_the_tracers_numpy_geometry(torso) -> None:
    """The renderer's one-pass kernel (float64 re-intersection, wall point, smooth normal facing
    the camera) against the tracer's numpy path, TracerScene.first_hit and smooth_normals, on the
    rays of a 96 px frame in the colon plus rays from outside the body (misses). Same formulas,
    different arithmetic order: distances and normals to 1e-12."""
    from raytrace.engine.scene import scene_for
    from vision.kernels import wall_hits

    scene = scene_for(torso)
    tables = scene.kernel_tables
    pose = Pose(torso.sites["ascending_colon"].position_m, [0.2, 0.1, 1.0], 10.0)
    cam = FisheyeCamera(150.0, 96)
    dirs = np.ascontiguousarray(pose.world_directions(cam)[cam.mask])
    dirs[:50] = [0.0, 0.0, 1.0]
    origin = np.asarray(pose.position_m, float)
    for o in (origin, origin + [0.0, 0.0, 10.0]):  # inside the colon; far above the torso (all miss)
        want_face, want_t = scene.first_hit(np.broadcast_to(o, dirs.shape), dirs)
        prim, tfar, _, _ = scene.embree.intersect(np.broadcast_to(o - scene.center, dirs.shape), dirs)
        n = len(dirs)
        face, t, points, normals = np.empty(n, np.int64), np.empty(n), np.empty((n, 3)), np.empty((n, 3))
        wall_hits(prim, tfar, o, dirs, tables.face_map, tables.face_normals, tables.plane_d, tables.frame,
                  face, t, points, normals)
        np.testing.assert_array_equal(face, want_face)
        hit = want_face >= 0
        assert hit.mean() == (1.0 if o is origin else 0.0)
        np.testing.assert_allclose(t[hit], want_t[hit], rtol=1e-12)
        assert np.isinf(t[~hit]).all() and np.isnan(points[~hit]).all() and not normals[~hit].any()
        p = o + want_t[hit, None] * dirs[hit]
        np.testing.assert_allclose(points[hit], p, rtol=0, atol=1e-12)
        want_n = scene.smooth_normals(want_face[hit], p)
        want_n *= np.where(np.einsum("ij,ij->i", want_n, dirs[hit]) > 0.0, -1.0, 1.0)[:, None]
        np.testing.assert_allclose(normals[hit], want_n, rtol=0, atol=1e-12)


def test_the_texture_belongs_to_the_wall_not_the_pixel(torso) -> None:
    """Two poses that see the same wall point give it the same reflectance: the mucosa is a
    function of the 3-D point (solid noise), so consecutive frames are consistent."""
    c = torso.sites["transverse_colon"].position_m
    tex = MucosaTexture.colon(fold_axis=(1, 0, 0))
    pts = render_frame(torso, Pose(c, [1, 0, 0]), FisheyeCamera(150.0, 48)).points_m
    pts = pts[np.isfinite(pts[..., 0])]
    nrm = np.tile([0.0, 0.0, 1.0], (len(pts), 1))
    a1, n1 = tex.shade_inputs(pts, nrm)
    order = np.random.default_rng(0).permutation(len(pts))
    a2, n2 = tex.shade_inputs(pts[order], nrm[order])
    np.testing.assert_array_equal(a1[order], a2)
    np.testing.assert_array_equal(n1[order], n2)
    assert a1.std(axis=0).min() > 0.01  # and it is a texture, not a flat colour


def test_the_pose_must_be_inside_the_named_lumen(torso) -> None:
    c = torso.sites["stomach"].position_m
    with pytest.raises(VisionInputError) as e:
        render_frame(torso, Pose(c, [0, 0, 1]), FisheyeCamera(90, 16), organ="small_intestine")
    assert e.value.field == "pose.position_m" and "stomach" in e.value.reason
    with pytest.raises(VisionInputError) as e:
        render_frame(torso, Pose(c, [0, 0, 1]), FisheyeCamera(90, 16), organ="appendix")
    assert e.value.field == "organ"
    with pytest.raises(VisionInputError) as e:
        render_frame(torso, Pose([1.0, 1.0, 1.0], [0, 0, 1]), FisheyeCamera(90, 16))
    assert e.value.field == "pose.position_m"
    for kwargs, field in ((dict(fov_deg=5.0), "camera.fov_deg"), (dict(size_px=8), "camera.size_px")):
        with pytest.raises(VisionInputError) as e:
            FisheyeCamera(**kwargs)
        assert e.value.field == field
    with pytest.raises(VisionInputError) as e:
        Pose(c, [0, 0, 0])
    assert e.value.field == "pose.direction"


def test_the_sensor_vignetting_noise_and_salt_and_pepper() -> None:
    """Vignetting is 1 - v (r / R)^2 exactly; shot noise has the Poisson variance mean / full
    well (within 5 sd of its sampling error); salt and pepper sets the stated fraction of pixels
    to 0 or 1 (binomial, 5 sd); the same seed and frame index give the same noise."""
    cam = FisheyeCamera(150.0, 128)
    rf = cam.theta / math.radians(75.0)
    flat = np.full((128, 128, 3), 0.5)
    out = SensorModel(vignetting=0.4, gamma=None, quantize_8bit=False).apply(flat, rf, cam.mask)
    np.testing.assert_allclose(out[cam.mask][:, 0], 0.5 * (1 - 0.4 * rf[cam.mask] ** 2), rtol=1e-12)
    assert (out[~cam.mask] == 0).all()

    well = 2000.0
    noisy = SensorModel(vignetting=0.0, full_well_electrons=well, gamma=None, quantize_8bit=False, seed=3)
    values = noisy.apply(flat, rf, cam.mask)[cam.mask].ravel()
    n = values.size
    var = 0.5 / well
    assert abs(values.mean() - 0.5) < 5 * math.sqrt(var / n)
    assert abs(values.var() / var - 1) < 5 * math.sqrt(2 / n)
    np.testing.assert_array_equal(values, noisy.apply(flat, rf, cam.mask)[cam.mask].ravel())
    assert not np.array_equal(values, noisy.apply(flat, rf, cam.mask, frame_index=1)[cam.mask].ravel())

    sp = SensorModel(vignetting=0.0, gamma=None, quantize_8bit=False, salt_pepper=0.05, seed=1)
    img = sp.apply(np.full((128, 128, 3), 0.5), rf, np.ones((128, 128), bool))
    hit = img[..., 0] != 0.5
    assert set(np.unique(img[hit])) <= {0.0, 1.0}
    assert abs(hit.mean() - 0.05) < 5 * math.sqrt(0.05 * 0.95 / hit.size)


def test_png_frames_read_back_with_an_independent_decoder(tmp_path) -> None:
    """vision.png writes what ITK's PNG reader (libpng, through SimpleITK) reads back exactly,
    RGB and grey."""
    import SimpleITK as sitk

    from vision.png import encode_png

    rng = np.random.default_rng(5)
    for image in (rng.integers(0, 256, (17, 23, 3), dtype=np.uint8), rng.integers(0, 256, (9, 31), dtype=np.uint8)):
        path = tmp_path / "frame.png"
        path.write_bytes(encode_png(image))
        np.testing.assert_array_equal(sitk.GetArrayFromImage(sitk.ReadImage(str(path))), image)
    with pytest.raises(VisionInputError):
        encode_png(np.zeros((4, 4), np.float32))
