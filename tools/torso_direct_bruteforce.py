"""Independent brute-force check: does a refraction-only (direct) GO path exist for each
capsule x sensor pair of the default torso (contact sensors)?

Shares no search code with the tracer (own ray walk, own Snell with Re n, own medium tracking,
own search); uses only the phantom's surface model (Embree first hits + smooth normals).

1. Lattice containment: a theta-phi launch lattice (NT x 2 NT rays), each ray walked
   refraction-only (stop at total internal reflection or in air). Its leg in the receiver's
   medium is intersected with the plane through the receiver tangent to the skin. A lattice
   triangle whose three rays share one signature and whose landing triangle contains the
   receiver proves a path (up to the map's linearity within one cell); it is polished by a
   derivative-free zoom (miss < 1e-7 m => EXISTS).
2. Fibonacci + zoom: the N rays passing closest to each receiver are zoomed (grid search on
   the launch direction minimising the closest approach) - this finds near-critical slivers
   narrower than a lattice cell.
A pair reported NONE by both at 4e6 rays is a GO shadow unless a sliver hides below that
resolution (see docs/tracer.md). Sensors: the torso's sensor sites, or with UNIFORM=1 in the
environment the uniform-belt positions of tests/raytrace/test_tracer_torso.py (UNIFORM_BELT), where
its GO_SHADOWS were established. Usage:
    [UNIFORM=1] .venv/bin/python tools/torso_direct_bruteforce.py [NT=1400] [N_FIB=2e6] [capsule,...]
Takes ~3 minutes for all 72 pairs on 2 cores.
"""

import os
import sys
import time

import numpy as np

import raytrace.body.torso as T
from raytrace.engine.scene import scene_for
from raytrace.solver.launch import fibonacci_sphere
from raytrace.solver.media import MediaTable

NT = int(sys.argv[1]) if len(sys.argv) > 1 else 1400
N_FIB = int(float(sys.argv[2])) if len(sys.argv) > 2 else 2_000_000
NP = 2 * NT

ph = T.build_torso()
sc = scene_for(ph)
media = MediaTable.build(ph, np.array([402e6]))
nre = media.n_real
parent = np.asarray(ph.parent)
forg = sc.face_organ
caps = [n for n, s in ph.sites.items() if s.kind == 'capsule']
only = sys.argv[3].split(',') if len(sys.argv) > 3 else None

if os.environ.get("UNIFORM"):
    sys.path.insert(0, os.path.join(os.path.dirname(__file__), "..", "tests"))
    from test_tracer_torso import UNIFORM_BELT
    sens = list(UNIFORM_BELT)
    RX = np.array([T.contact_point(ph, deg, z) for deg, z in UNIFORM_BELT.values()])
    RXM = np.full(len(RX), ph.organ_index("skin"))
else:
    sens = [n for n, s in ph.sites.items() if s.kind == 'sensor']
    RX = np.array([ph.sites[s].position_m for s in sens])
    RXM = np.array([ph.organ_index(ph.sites[s].medium) for s in sens])
A_SKIN, B_SKIN = 0.163, 0.119
NRM = np.stack([RX[:, 0] / A_SKIN**2, RX[:, 1] / B_SKIN**2, 0 * RX[:, 0]], 1)
NRM /= np.linalg.norm(NRM, axis=1, keepdims=True)
E1 = np.cross(NRM, [0, 0, 1.0])
E1 /= np.linalg.norm(E1, axis=1, keepdims=True)
E2 = np.cross(NRM, E1)
WINDOW = 0.03
MAXEV = 14


def walk(tx, txm, dirs):
    """Returns sig (P,) int64 signature hash at the receiver-medium leg and land (P, R, 2)."""
    p = len(dirs)
    o = np.broadcast_to(tx, (p, 3)).copy()
    d = dirs.copy()
    med = np.full(p, txm)
    push = np.zeros((p, 3))
    alive = np.ones(p, bool)
    sig = np.zeros(p, np.int64)
    land = np.full((p, len(RX), 2), np.nan)
    lsig = np.full((p, len(RX)), -1, np.int64)
    miss = np.full((p, len(RX)), np.inf)
    for _ in range(MAXEV + 20):
        idx = np.flatnonzero(alive)
        if len(idx) == 0:
            break
        face, t = sc.first_hit(o[idx], d[idx], push[idx])
        tt = np.where(face >= 0, t, 10.0)
        for r in range(len(RX)):
            s = np.flatnonzero(med[idx] == RXM[r])
            if len(s) == 0:
                continue
            i = idx[s]
            v = RX[r] - o[i]
            tp = np.clip(np.einsum('ij,ij->i', v, d[i]), 0.0, tt[s])
            miss[i, r] = np.minimum(miss[i, r], np.linalg.norm(v - tp[:, None] * d[i], axis=1))
            dn = d[i] @ NRM[r]
            with np.errstate(divide='ignore', invalid='ignore'):
                tc = (v @ NRM[r]) / dn
            x = o[i] + tc[:, None] * d[i] - RX[r]
            ok = (tc >= -1e-9) & (tc <= tt[s] + 1e-9) & (np.linalg.norm(x, axis=1) < WINDOW)
            land[i[ok], r, 0] = x[ok] @ E1[r]
            land[i[ok], r, 1] = x[ok] @ E2[r]
            lsig[i[ok], r] = sig[i[ok]]
        hit = face >= 0
        alive[idx[~hit]] = False
        j = idx[hit]
        f = face[hit]
        pt = o[j] + t[hit, None] * d[j]
        fn = sc.face_normals[f]
        leaving = np.einsum('ij,ij->i', d[j], fn) > 0
        org = forg[f]
        mfrom = np.where(leaving, org, parent[org])
        mto = np.where(leaving, parent[org], org)
        bad = mfrom != med[j]
        ns = sc.smooth_normals(f, pt)
        n1, n2 = nre[mfrom + 1], nre[mto + 1]
        cosi = np.einsum('ij,ij->i', d[j], ns)
        sg = np.sign(cosi)
        ci = np.abs(cosi)
        eta = n1 / n2
        k = 1 - eta**2 * (1 - ci**2)
        tir = k < 0
        ct = np.sqrt(np.clip(k, 0, None))
        nd = eta[:, None] * d[j] + (sg * (ct - eta * ci))[:, None] * ns
        nd /= np.linalg.norm(nd, axis=1, keepdims=True)
        wrong = np.einsum('ij,ij->i', nd, fn) * np.where(leaving, 1, -1) <= 0
        transparent = n1 == n2
        stop = bad | tir | wrong | (mto == -1)
        alive[j[stop]] = False
        g = ~stop
        jg = j[g]
        code = (org * 2 + leaving) * 1 + 1
        sig[jg] = np.where(transparent[g], sig[jg], (sig[jg] * 1_000_003 + code[g]) % (1 << 61))
        o[jg] = pt[g]
        d[jg] = nd[g]
        med[jg] = mto[g]
        push[jg] = np.where(leaving[g], 1.0, -1.0)[:, None] * fn[g] * sc.offset_m
    return lsig, land, miss


def lattice(i0, i1):
    th = (np.arange(i0, i1) + 0.5) * np.pi / NT
    ph_ = np.arange(NP) * 2 * np.pi / NP
    TH, PH = np.meshgrid(th, ph_, indexing='ij')
    return np.stack([np.sin(TH) * np.cos(PH), np.sin(TH) * np.sin(PH), np.cos(TH)], -1).reshape(-1, 3)


def contains(a, b, c):
    """Origin inside triangle abc (arrays (K,2)); returns mask and barycentrics."""
    v0, v1 = b - a, c - a
    den = v0[:, 0] * v1[:, 1] - v0[:, 1] * v1[:, 0]
    with np.errstate(divide='ignore', invalid='ignore'):
        l1 = (-a[:, 0] * v1[:, 1] + a[:, 1] * v1[:, 0]) / den
        l2 = (-v0[:, 0] * a[:, 1] + v0[:, 1] * a[:, 0]) / den
    ok = (l1 >= 0) & (l2 >= 0) & (l1 + l2 <= 1) & np.isfinite(den) & (den != 0)
    return ok, l1, l2


def zoom(tx, txm, d0, r, scale, levels=30, g=9):
    best = np.inf
    for _ in range(levels):
        ref = np.array([1.0, 0, 0]) if abs(d0[0]) < 0.9 else np.array([0, 1.0, 0])
        u = np.cross(d0, ref)
        u /= np.linalg.norm(u)
        v = np.cross(d0, u)
        a = np.linspace(-scale, scale, g)
        A, B = np.meshgrid(a, a)
        dd = d0 + A.ravel()[:, None] * u + B.ravel()[:, None] * v
        dd /= np.linalg.norm(dd, axis=1, keepdims=True)
        m = walk(tx, txm, dd)[2][:, r]
        k = int(np.argmin(m))
        if m[k] <= best:
            best = m[k]
            d0 = dd[k]
        scale *= 0.5
        if best < 1e-10:
            break
    return best, d0


ROWS = 100
for c in caps:
    if only and c not in only:
        continue
    t0 = time.time()
    tx = ph.sites[c].position_m
    txm = ph.organ_index(ph.sites[c].medium)
    hits = [[] for _ in RX]
    nearest = np.full(len(RX), np.inf)
    spacing = np.full(len(RX), np.nan)
    prev = None
    for i0 in range(0, NT, ROWS):
        i1 = min(i0 + ROWS, NT)
        dirs = lattice(i0, i1)
        lsig, land, miss = walk(tx, txm, dirs)
        nearest = np.minimum(nearest, miss.min(axis=0))
        rows = i1 - i0
        lsig = lsig.reshape(rows, NP, len(RX))
        land = land.reshape(rows, NP, len(RX), 2)
        dirs = dirs.reshape(rows, NP, 3)
        if prev is not None:
            lsig = np.concatenate([prev[0], lsig])
            land = np.concatenate([prev[1], land])
            dirs = np.concatenate([prev[2], dirs])
        prev = (lsig[-1:], land[-1:], dirs[-1:])
        for r in range(len(RX)):
            S = lsig[:, :, r]
            L = land[:, :, r]
            S1 = np.roll(S, -1, axis=1)
            L1 = np.roll(L, -1, axis=1)
            for (sa, la), (sb, lb), (sc_, lc) in (
                ((S[:-1], L[:-1]), (S[1:], L[1:]), (S1[1:], L1[1:])),
                ((S[:-1], L[:-1]), (S1[1:], L1[1:]), (S1[:-1], L1[:-1])),
            ):
                same = (sa >= 0) & (sa == sb) & (sa == sc_)
                ii = np.argwhere(same)
                if len(ii) == 0:
                    continue
                a_, b_, c_ = la[same], lb[same], lc[same]
                ok, l1, l2 = contains(a_, b_, c_)
                for k in np.flatnonzero(ok):
                    ri, pj = ii[k]
                    hits[r].append(dirs[ri, pj])
    # 2. Fibonacci + zoom from the closest rays
    fib = fibonacci_sphere(N_FIB)
    sp = np.sqrt(4 * np.pi / N_FIB)
    fmiss = np.full((N_FIB, len(RX)), np.inf)
    for a in range(0, N_FIB, 250_000):
        fmiss[a:a + 250_000] = walk(tx, txm, fib[a:a + 250_000])[2]
    for r, s in enumerate(sens):
        n_tri = len(hits[r])
        z1 = min((zoom(tx, txm, h, r, np.pi / NT)[0] for h in hits[r][:3]), default=np.inf)
        seeds = []
        for i in np.argsort(fmiss[:, r])[:400]:
            if not np.isfinite(fmiss[i, r]):
                break
            if all(fib[i] @ fib[k] < np.cos(3 * sp) for k in seeds):
                seeds.append(i)
            if len(seeds) == 6:
                break
        z2 = min((zoom(tx, txm, fib[i], r, 3 * sp)[0] for i in seeds), default=np.inf)
        verdict = 'EXISTS' if min(z1, z2) < 1e-7 else 'NONE'
        print(f'{c:18s} {s:22s} containing_cells={n_tri:4d} nearest_leg={nearest[r]*1e3:8.3f} mm '
              f'lattice_zoom={z1:.1e} m fib_zoom={z2:.1e} m  {verdict}', flush=True)
    print(c, f'{time.time()-t0:.1f}s', flush=True)
