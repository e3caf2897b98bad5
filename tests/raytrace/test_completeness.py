"""Completeness: every geometric-optics path above the dynamic range is found, once, exactly.

The scenes are planar, so the oracle is the image method, written here and sharing no code
with the tracer: every sequence of faces (no face twice in a row) up to the depth, the
transmitter mirrored across each face in turn, the path traced back from the receiver to the
images, and kept when every reflection point lies on its face's rectangle. The air region of
every scene is convex (an intersection of the faces' half-spaces), so a valid unfolded path
is never blocked. Gains: the vector field of the isotropic antennas' normalised transverse
polarizations, reflected at each face with the Fresnel coefficients of a lossy half-space
(Born & Wolf 1.5.20-21, exp(+j w t): eps_c = eps_r - j sigma / (w eps0)), spread as
1 / (unfolded length), phase k0 L: a = lambda0 / (4 pi L) (e_rx . E) exp(-j k0 L).

Several faces of one organ share one interaction signature (organ, side, kind), which is
what these scenes test: the box room as ONE closed organ (its six walls share a signature)
against the same room cut into six separate slabs, a trihedral corner reflector and a
U-shaped channel (a concave organ with two specular points per single reflection and
flutter echoes between its walls), each one organ.

Tolerances: delays 0.1 ps (float64 paths are exact to ~1e-23 s here; 0.1 ps is the suite's
delay tolerance everywhere), gains 1e-6 dB (planar faces: the ray-differential tube and the
Fresnel coefficients are exact, measured ~4e-11 dB). Found: at least 99 % of the oracle's
paths above the dynamic range at 1e5 rays (the issue's acceptance), and every missed one
must graze an edge (a reflection point within ``EDGE_M`` of its face's border, where the
neighbouring rays change face and shooting samples the path poorly).
"""

from __future__ import annotations

import itertools

import numpy as np
import pytest
import trimesh

import raytrace as rt
from raytrace.body.phantom import Material, Organ, Phantom
from tests.helpers import trace

C = 299_792_458.0
EPS0 = 8.8541878128e-12
F = 3.5e9
CONCRETE = (5.24, 0.0462)  # eps_r, sigma [S/m] at 3.5 GHz (ITU-R P.2040 concrete)
DYNAMIC_RANGE_DB = 80.0
EDGE_M = 0.1
Z = np.array([0.0, 0.0, 1.0])


def concrete() -> Material:
    return Material(relative_permittivity=CONCRETE[0], conductivity_s_per_m=CONCRETE[1])


# ------------------------------------------------------------------ the oracle
class Face:
    """A rectangle ``origin + s u + t v`` (s, t in [0, 1]) whose unit ``normal`` points into the air."""

    def __init__(self, origin, u, v, normal):
        self.origin, self.u, self.v = (np.asarray(a, float) for a in (origin, u, v))
        self.normal = np.asarray(normal, float) / np.linalg.norm(normal)

    def mirror(self, p):
        return p - 2.0 * ((p - self.origin) @ self.normal) * self.normal

    def coords(self, p):
        """(s, t) of a point of the face's plane."""
        m = np.array([self.u, self.v]).T
        st, *_ = np.linalg.lstsq(m, p - self.origin, rcond=None)
        return st

    def edge_distance(self, p):
        s, t = self.coords(p)
        lu, lv = np.linalg.norm(self.u), np.linalg.norm(self.v)
        return min(s * lu, (1 - s) * lu, t * lv, (1 - t) * lv)


def box_faces(lo, hi):
    """The six inner faces of the box [lo, hi] (normals into the box)."""
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    faces = []
    for ax in range(3):
        a, b = [o for o in range(3) if o != ax]
        for side, plane in ((1.0, lo[ax]), (-1.0, hi[ax])):
            origin = lo.copy()
            origin[ax] = plane
            u, v, n = np.zeros(3), np.zeros(3), np.zeros(3)
            u[a], v[b], n[ax] = hi[a] - lo[a], hi[b] - lo[b], side
            faces.append(Face(origin, u, v, n))
    return faces


def image_paths(faces, tx, rx, depth, eps_r, sigma, tx_pol, rx_pol):
    """Every specular path from ``tx`` to ``rx`` with up to ``depth`` reflections on ``faces``:
    dicts of ``points`` (tx, reflection points, rx), ``delay_s``, complex ``gain``, ``edge_m``
    (the smallest distance of a reflection point to its face's border)."""
    lam = C / F
    eps_c = eps_r - 1j * sigma / (2 * np.pi * F * EPS0)
    out = []
    for n in range(depth + 1):
        for seq in itertools.product(range(len(faces)), repeat=n):
            if any(seq[i] == seq[i + 1] for i in range(n - 1)):
                continue
            images = [np.asarray(tx, float)]
            for f in seq:
                images.append(faces[f].mirror(images[-1]))
            target, points, ok = np.asarray(rx, float), [], True
            for k in range(n, 0, -1):
                face, img = faces[seq[k - 1]], images[k]
                d = target - img
                denom = d @ face.normal
                if abs(denom) < 1e-12:
                    ok = False
                    break
                t = ((face.origin - img) @ face.normal) / denom
                p = img + t * d
                s, q = face.coords(p)
                if not (1e-12 < t < 1 - 1e-12 and 0.0 <= s <= 1.0 and 0.0 <= q <= 1.0):
                    ok = False
                    break
                points.append(p)
                target = p
            if not ok:
                continue
            pts = [np.asarray(tx, float)] + points[::-1] + [np.asarray(rx, float)]
            legs = [pts[i + 1] - pts[i] for i in range(len(pts) - 1)]
            length = sum(np.linalg.norm(g) for g in legs)
            dirs = [g / np.linalg.norm(g) for g in legs]
            e = tx_pol - dirs[0] * (dirs[0] @ tx_pol)
            e = (e / np.linalg.norm(e)).astype(complex)
            for i, f in enumerate(seq):
                k_in, k_out, nrm = dirs[i], dirs[i + 1], faces[f].normal
                cos_i = -(k_in @ nrm)
                root = np.sqrt(eps_c - (1.0 - cos_i**2))  # n2 cos_t, the decaying branch
                r_s = (cos_i - root) / (cos_i + root)
                r_p = (eps_c * cos_i - root) / (eps_c * cos_i + root)
                s = np.cross(k_in, nrm)
                s /= np.linalg.norm(s)
                e = r_s * (e @ s) * s + r_p * (e @ np.cross(s, k_in)) * np.cross(s, k_out)
            r = rx_pol - dirs[-1] * (dirs[-1] @ rx_pol)
            r /= np.linalg.norm(r)
            edge = min((faces[f].edge_distance(p) for f, p in zip(seq, points[::-1])), default=np.inf)
            gain = lam / (4 * np.pi * length) * (r @ e) * np.exp(-2j * np.pi * length / lam)
            out.append({"points": pts, "delay_s": length / C, "gain": gain, "edge_m": edge})
    return out


def test_oracle_counts_the_box_lattice():
    """The oracle itself: in a box every image (i, j, k) with |i| + |j| + |k| <= depth gives one
    path (4 k^2 + 2 images at k reflections), whatever the positions: 63 at depth 3, 231 at 5."""
    faces = box_faces(ROOM_LO, ROOM_HI)
    for depth, count in ((3, 63), (5, 231)):
        assert len(image_paths(faces, TX, RXS[0], depth, *CONCRETE, Z, Z)) == count


# ------------------------------------------------------------------ scenes
ROOM_LO, ROOM_HI = np.array([-3.0, -2.5, -1.5]), np.array([3.0, 2.5, 1.5])
TX = np.array([0.7, -0.4, 0.2])
RXS = [np.array([-1.3, 1.1, -0.35]), np.array([2.1, 1.7, 0.6]), np.array([-2.2, -1.6, 0.9]),
       np.array([0.4, 0.9, -1.0])]


def room_one_organ() -> Phantom:
    """The room's air as one organ (its six walls one signature) inside a 1 m concrete shell."""
    walls = trimesh.creation.box(bounds=[ROOM_LO - 1.0, ROOM_HI + 1.0])
    air = trimesh.creation.box(bounds=[ROOM_LO, ROOM_HI])
    return Phantom.build("room-one-organ", [
        Organ("walls", concrete(), walls),
        Organ("room", Material(relative_permittivity=1.0, conductivity_s_per_m=0.0), air)])


def room_six_slabs(gap_m: float = 1e-3) -> Phantom:
    """The same room as six 1 m concrete slabs in air, ``gap_m`` apart at the room's edges
    (organs may not touch)."""
    organs = []
    for ax in range(3):
        for side in (0, 1):
            lo, hi = ROOM_LO + gap_m, ROOM_HI - gap_m
            if side == 0:
                lo[ax], hi[ax] = ROOM_LO[ax] - 1.0, ROOM_LO[ax]
            else:
                lo[ax], hi[ax] = ROOM_HI[ax], ROOM_HI[ax] + 1.0
            organs.append(Organ(f"wall_{'xyz'[ax]}{side}", concrete(), trimesh.creation.box(bounds=[lo, hi])))
    return Phantom.build("room-six-slabs", organs)


def voxel_solid(edges, filled) -> trimesh.Trimesh:
    """A closed, outward-oriented mesh of the union of grid cells: ``edges`` the three axes'
    cell boundaries, ``filled`` the (i, j, k) cells. Each face between a filled and an empty
    cell becomes two triangles (an independent, hand-built mesh for concave organs)."""
    filled = set(filled)
    verts, faces, index = [], [], {}

    def vid(i, j, k):
        key = (i, j, k)
        if key not in index:
            index[key] = len(verts)
            verts.append([edges[0][i], edges[1][j], edges[2][k]])
        return index[key]

    for cell in sorted(filled):
        for ax in range(3):
            for step in (-1, 1):
                nb = list(cell)
                nb[ax] += step
                if tuple(nb) in filled:
                    continue
                a, b = [o for o in range(3) if o != ax]
                base = list(cell)
                base[ax] += 1 if step > 0 else 0
                corners = []
                for da, db in ((0, 0), (1, 0), (1, 1), (0, 1)):
                    c = list(base)
                    c[a] += da
                    c[b] += db
                    corners.append(vid(*c))
                # (a, b, ax) is right-handed for ax = 0 and 2 and left-handed for ax = 1
                outward = (step > 0) == (ax != 1)
                quad = corners if outward else corners[::-1]
                faces += [[quad[0], quad[1], quad[2]], [quad[0], quad[2], quad[3]]]
    mesh = trimesh.Trimesh(np.array(verts, float), np.array(faces), process=True)
    assert mesh.is_watertight and mesh.is_winding_consistent and mesh.volume > 0
    return mesh


def corner_reflector():
    """A 2 m concrete cube with its (+, +, +) octant cut out: three walls of one organ meeting
    at a right-angled corner (at 0.2 m). Returns the phantom and the three inner faces."""
    e = [-0.0, 0.2, 2.0]
    cells = [c for c in itertools.product(range(2), repeat=3) if c != (1, 1, 1)]
    ph = Phantom.build("corner-reflector", [Organ("reflector", concrete(), voxel_solid([e, e, e], cells))])
    t, a = 0.2, 1.8
    faces = [Face([t, t, t], [0, a, 0], [0, 0, a], [1, 0, 0]), Face([t, t, t], [a, 0, 0], [0, 0, a], [0, 1, 0]),
             Face([t, t, t], [a, 0, 0], [0, a, 0], [0, 0, 1])]
    return ph, faces


def u_channel():
    """A concave organ: a 3 m long concrete channel, walls 1.2 m apart and 1.5 m high over a
    floor (walls and floor 0.3 m thick), open on top and at both ends. Two walls of one
    organ face each other: two specular points per single reflection, flutter echoes."""
    xs, ys, zs = [0.0, 0.3, 1.5, 1.8], [0.0, 0.3, 1.8], [0.0, 3.0]
    cells = [(0, 0, 0), (1, 0, 0), (2, 0, 0), (0, 1, 0), (2, 1, 0)]
    ph = Phantom.build("u-channel", [Organ("channel", concrete(), voxel_solid([xs, ys, zs], cells))])
    faces = [Face([0.3, 0.3, 0.0], [0, 1.5, 0], [0, 0, 3.0], [1, 0, 0]),
             Face([1.5, 0.3, 0.0], [0, 1.5, 0], [0, 0, 3.0], [-1, 0, 0]),
             Face([0.3, 0.3, 0.0], [1.2, 0, 0], [0, 0, 3.0], [0, 1, 0])]
    return ph, faces


# ------------------------------------------------------------------ the check
def _points(path) -> np.ndarray:
    return np.array([i.point_m for i in path.interactions], float).reshape(-1, 3)


def check_complete(result, oracle_per_rx, air_media):
    """Match the tracer's reflection-only paths in ``air_media`` to the oracle's, receiver by
    receiver. Returns (above the dynamic range, found, missed oracle paths); asserts each found
    path's delay and gain, that no oracle path is found twice and no tracer path is unknown."""
    above = found = 0
    missed = []
    for prof, oracle in zip(result.profiles, oracle_per_rx):
        top = max(abs(o["gain"]) for o in oracle)
        ours = [p for p in prof.paths if all(i.kind == "reflection" for i in p.interactions)
                and all(s.medium in air_media for s in p.segments)]
        delays = np.array([p.delay_s for p in ours])
        used = set()
        for o in oracle:
            level_db = 20 * np.log10(abs(o["gain"]) / top)
            if level_db < -DYNAMIC_RANGE_DB + 0.01:
                continue  # below the dynamic range (or within 0.01 dB of it: either answer is right)
            above += 1
            pts = np.array(o["points"][1:-1]).reshape(-1, 3)
            near = np.flatnonzero(np.abs(delays - o["delay_s"]) < 1e-11)  # then by the points themselves
            match = [j for j in near if len(ours[j].interactions) == len(pts)
                     and np.allclose(_points(ours[j]), pts, atol=1e-6)]
            assert len(match) <= 1, f"{prof.receiver}: one path found {len(match)} times"
            if not match:
                missed.append((prof.receiver, level_db, o["edge_m"]))
                continue
            found += 1
            used.add(match[0])
            p = ours[match[0]]
            assert abs(p.delay_s - o["delay_s"]) < 1e-13
            assert abs(20 * np.log10(abs(p.gain) / abs(o["gain"]))) < 1e-6
            assert abs(np.angle(p.gain / o["gain"])) < 1e-6  # the same phase (rad)
        unknown = [p for j, p in enumerate(ours) if j not in used]
        # every tracer path is an oracle path (possibly one below the floor margin)
        for p in unknown:
            known = any(len(p.interactions) == len(o["points"]) - 2 and np.allclose(
                _points(p), np.array(o["points"][1:-1]).reshape(-1, 3), atol=1e-6) for o in oracle)
            assert known, f"{prof.receiver}: a path the image method does not have: {p}"
    return above, found, missed


def assert_complete(above, found, missed):
    assert found >= 0.99 * above, (found, above, missed)
    assert all(edge < EDGE_M for _, _, edge in missed), missed


@pytest.mark.parametrize("depth", [3, pytest.param(5, marks=pytest.mark.slow)])
def test_box_room_one_organ_finds_what_six_slabs_find(depth):
    """The acceptance of issue 17: the room as one closed organ finds >= 99 % of the image
    paths above the dynamic range at 1e5 rays, and at least as many as the six slabs (before
    per-path clustering: 76 of 252 at depth 3 against 252)."""
    faces = box_faces(ROOM_LO, ROOM_HI)
    oracle = [image_paths(faces, TX, rx, depth, *CONCRETE, Z, Z) for rx in RXS]
    counts = {}
    for name, ph, air in (("one", room_one_organ(), {"room"}), ("six", room_six_slabs(), {"air"})):
        res = trace(ph, rt.Antenna(TX, polarization=Z), [rt.Antenna(r, polarization=Z) for r in RXS], F,
                    rays=100_000, max_interactions=depth, dynamic_range_db=DYNAMIC_RANGE_DB)
        counts[name] = check_complete(res, oracle, air)
        assert_complete(*counts[name])
    assert counts["one"][0] == counts["six"][0] == (252 if depth == 3 else 834)  # 90 of 924 below 80 dB at depth 5
    assert counts["one"][1] >= counts["six"][1]


def test_corner_reflector():
    """Trihedral corner, one organ: direct, three single, the double and triple reflections
    (the three walls share a signature)."""
    ph, faces = corner_reflector()
    tx = np.array([0.9, 1.3, 0.7])
    rxs = [np.array([1.4, 0.6, 1.1]), np.array([0.5, 0.8, 1.6]), np.array([1.7, 1.5, 0.4])]
    pol = np.array([0.3, -0.5, 0.8])
    oracle = [image_paths(faces, tx, rx, 3, *CONCRETE, pol, pol) for rx in rxs]
    res = trace(ph, rt.Antenna(tx, polarization=pol), [rt.Antenna(r, polarization=pol) for r in rxs], F,
                rays=100_000, max_interactions=3, dynamic_range_db=DYNAMIC_RANGE_DB)
    above, found, missed = check_complete(res, oracle, {"air"})
    assert above >= 3 * 8 - 3  # at most one double / triple image invalid per receiver (positions)
    assert found == above, missed


def test_u_channel_two_specular_points_and_flutter_echoes():
    """Concave organ: both walls' single reflections (two specular points, one signature) and
    the flutter echoes between the walls and the floor, up to 4 reflections."""
    ph, faces = u_channel()
    tx = np.array([0.6, 0.9, 0.8])
    rxs = [np.array([1.2, 0.7, 2.3]), np.array([0.5, 1.4, 1.9])]
    pol = np.array([0.0, 1.0, 0.0])
    oracle = [image_paths(faces, tx, rx, 4, *CONCRETE, pol, pol) for rx in rxs]
    res = trace(ph, rt.Antenna(tx, polarization=pol), [rt.Antenna(r, polarization=pol) for r in rxs], F,
                rays=100_000, max_interactions=4, dynamic_range_db=DYNAMIC_RANGE_DB)
    above, found, missed = check_complete(res, oracle, {"air"})
    singles = [o for o in oracle[0] if len(o["points"]) == 3]
    assert len(singles) == 3  # two walls and the floor
    assert above > 20
    assert_complete(above, found, missed)


# ------------------------------------------------------------------ layered slab, oblique
def layered_path(legs, offset_m, n_tx):
    """A TE ray through horizontal layers (``legs``: (index, height) of each leg, lossless) from
    the transmitter to a receiver ``offset_m`` away horizontally: the ray parameter p from
    sum h_i p / sqrt(n_i^2 - p^2) = offset (monotonic: brentq), the delay sum n_i^2 h_i /
    sqrt(n_i^2 - p^2) / c, and the leg ends' horizontal positions."""
    from scipy.optimize import brentq

    n = np.array([leg[0] for leg in legs])
    h = np.array([leg[1] for leg in legs])

    def offset(p):
        return float(np.sum(h * p / np.sqrt(n**2 - p**2)))

    p = brentq(lambda q: offset(q) - offset_m, 0.0, n.min() * (1 - 1e-12), xtol=1e-300, rtol=1e-15, maxiter=500)
    cos = np.sqrt(1 - (p / n) ** 2)
    # tube per launch solid angle (docs/tracer.md "Normalisation"): X cos(theta_rx) (dX / dtheta_0) / sin(theta_0)
    dx_dp = float(np.sum(h * n**2 / (n**2 - p**2) ** 1.5))
    tube = offset_m * cos[-1] * dx_dp * n_tx * cos[0] / (p / n_tx)
    return p, float(np.sum(n * h / cos)) / C, np.cumsum(h * (p / n) / cos), cos, tube


def test_layered_slab_oblique_paths():
    """Slab B (eps 50, 20 mm) in A (eps 10), lossless, TE (polarization normal to the plane of
    incidence): above it the top-face echo and the paths bouncing once and
    twice off the bottom inside the slab; below it the transmitted path and its two internal
    echoes (up to 6 interactions). Delays from the ray parameter (Fermat in 1-D), gains from
    the Fresnel TE coefficients, the tube's jump sqrt(cos_t / cos_i) at each refraction and the
    point source's spreading behind planar layers."""
    eps_a, eps_b, d_slab, h1 = 10.0, 50.0, 0.02, 0.03
    n_a, n_b = np.sqrt(eps_a), np.sqrt(eps_b)
    lam = C / 402e6
    outer = trimesh.creation.box(extents=[2.0, 2.0, 2.0])
    slab = trimesh.creation.box(bounds=[[-0.4, -0.4, -d_slab], [0.4, 0.4, 0.0]])
    ph = Phantom.build("slab-oblique", [
        Organ("A", Material(relative_permittivity=eps_a, conductivity_s_per_m=0.0), outer),
        Organ("B", Material(relative_permittivity=eps_b, conductivity_s_per_m=0.0), slab)])
    y = np.array([0.0, 1.0, 0.0])
    tx = np.array([-0.03, 0.0, h1])
    above, below = np.array([0.05, 0.0, 0.025]), np.array([0.04, 0.0, -d_slab - 0.035])
    res = trace(ph, rt.Antenna(tx, polarization=y), [rt.Antenna(above, polarization=y),
                                                     rt.Antenna(below, polarization=y)], 402e6,
                rays=100_000, max_interactions=6, dynamic_range_db=120.0)

    def fresnel(n1, c1, n2, c2):
        return (n1 * c1 - n2 * c2) / (n1 * c1 + n2 * c2), 2 * n1 * c1 / (n1 * c1 + n2 * c2)

    # (receiver, interaction kinds A->B refraction "t", reflection inside A "ra", inside B "rb")
    cases = [(0, ["ra"]), (0, ["t", "rb", "t"]), (0, ["t", "rb", "rb", "rb", "t"]),
             (1, ["t", "t"]), (1, ["t", "rb", "rb", "t"]), (1, ["t", "rb", "rb", "rb", "rb", "t"])]
    for r, kinds in cases:
        rx = (above, below)[r]
        inside = len(kinds) - 2 if kinds[0] == "t" else 0
        if kinds == ["ra"]:
            legs = [(n_a, h1), (n_a, rx[2])]
        else:
            legs = [(n_a, h1)] + [(n_b, d_slab)] * (inside + 1) + [(n_a, abs(rx[2]) - (d_slab if r else 0.0))]
        offset = rx[0] - tx[0]
        p, delay, xs, cos, tube = layered_path(legs, offset, n_a)
        c_a, c_b = cos[0], np.sqrt(1 - (p / n_b) ** 2)
        r_ab, t_ab = fresnel(n_a, c_a, n_b, c_b)
        r_ba, t_ba = fresnel(n_b, c_b, n_a, c_a)
        if kinds == ["ra"]:
            factor = r_ab
        else:
            factor = t_ab * np.sqrt(c_b / c_a) * r_ba ** inside * t_ba * np.sqrt(c_a / c_b)
        phase = np.exp(-2j * np.pi / lam * sum(n * h / c for (n, h), c in zip(legs, cos)))
        gain = lam / (4 * np.pi) * factor * phase / np.sqrt(tube) / n_a
        # the oracle's interaction points: the legs' ends on z = 0 or z = -d_slab
        zs = [0.0] + [-d_slab if j % 2 == 0 else 0.0 for j in range(len(legs) - 2)]
        pts = np.array([[tx[0] + x, 0.0, zz] for x, zz in zip(xs[:-1], zs)])
        match = [p_ for p_ in res.profiles[r].paths if len(p_.interactions) == len(pts)
                 and np.allclose(_points(p_), pts, atol=1e-6)]
        assert len(match) == 1, (r, kinds, len(match))
        got = match[0]
        assert abs(got.delay_s - delay) < 1e-13
        assert abs(20 * np.log10(abs(got.gain) / abs(gain))) < 1e-6, (kinds, got.gain, gain)
        assert abs(np.angle(got.gain / gain)) < 1e-6
