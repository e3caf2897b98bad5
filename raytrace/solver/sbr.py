"""Shooting and bouncing rays: candidate interaction signatures for every receiver.

One launch (a Fibonacci sphere of directions at the transmitter) serves all
receivers; it is processed in batches of ``launch_batch`` directions,
each batch's whole bounce tree at once, so memory stays bounded without
culling branches. Per bounce, every live ray of the batch is cast together
(Embree batches of ``chunk_rays``); at each hit it splits into a
reflected ray and, unless Snell has no real solution (total internal
reflection), a transmitted ray, up to ``max_interactions`` events. The scene
given holds only the surfaces between different materials (see
:func:`raytrace.engine.scene.scene_for`), so media are compared by material class.
A ray's power factor (lossless Fresnel power reflectance / transmittance
from Re n, mean of TE and TM, times the true absorption ``exp(-2 alpha L)``)
prunes it once below the dynamic range; a safety cap on live rays keeps the
highest power / reduced-length^2 (deterministic partition). Shooting runs in
float32 (it only produces seeds; refinement is float64).

Reception: a segment passing within the reception radius of a receiver in
a medium of the same material makes a candidate. The radius is the ray tube's half-width,
grown along the unfolded path as ``angle * length`` with ``angle`` the launch
spacing sqrt(4 pi / N), multiplied at each refraction by the tube's angular
magnification ``max(n1 cos_i / (n2 cos_t), n1 / n2, 1)``, and widened at every
curved surface by what a thin mirror / lens of the surface's curvature ``k``
does to the tube's edge ray at half-width ``h``: ``2 k h`` on reflection,
``k h |1 - n1 / n2|`` on refraction (times ``curvature_margin``; ``k``
from :attr:`raytrace.engine.scene.TracerScene.face_curvature32`). Without that term
curved organs (colon, kidneys, spine, the skin's own curvature) spread the rays
of a reflected tube far beyond its modelled width, and receivers between them
got no candidate: on the default torso at 1e5 rays, 6 of 36 capsule x sensor
pairs lacked their strongest path. Candidates are only seeds:
:func:`raytrace.solver.refine.refine` makes every kept path exact.

The refraction-only seed walk of :func:`raytrace.solver.direct.direct_seeds` (``walk=True``) rides
on the same rays: its launch is this launch, and its rays are the branches that have only
refracted so far, which the shooting casts anyway. Each launch's closest approach to every
receiver is kept as the walk keeps it; where the shooting drops such a branch (dynamic range,
``max_interactions``) the walk alone carries it on, unpruned, to its own event cap. On the
default request this adds 14e3 casts to the shooting's 1.63e6 where the stand-alone walk cast
3.4e5, and gives the walk's seeds (same launches, signatures and event counts).
"""

from __future__ import annotations

from concurrent.futures import Executor, ThreadPoolExecutor
from dataclasses import dataclass, field

import numpy as np

from raytrace.engine import kernels
from raytrace.engine.boxgap import least_gap
from raytrace.engine.records import ShotMedia, ShotRays, ShotReceivers, ShotScene, ShotSettings, WalkRecords, build
from raytrace.engine.scene import TracerScene
from raytrace.physics.em import C0
from raytrace.solver.budget import Budget
from raytrace.solver.config import TracerConfig
from raytrace.solver.direct import Seeds, closest_launches, pick_seeds
from raytrace.solver.launch import angular_spacing_rad, fibonacci_sphere
from raytrace.solver.media import MediaTable


@dataclass
class Candidates:
    receiver: np.ndarray  # (C,) receiver index
    codes: np.ndarray  # (C, K) signature, -1 padded
    faces: np.ndarray  # (C, K) faces of the events, -1 padded
    nint: np.ndarray  # (C,)
    launch_dir: np.ndarray  # (C, 3)
    closeness: np.ndarray  # (C,) miss distance / reception radius
    rays_launched: int
    segments: int
    #: the refraction-only walk on the shooting's rays: per receiver, the closest launches of
    #: every batch (:func:`raytrace.solver.direct.closest_launches`), in batch order; None if not walked
    walk: list[list[tuple]] | None = None

    def direct_seeds(self, receivers: np.ndarray, config: TracerConfig | None = None) -> Seeds:
        """:func:`raytrace.solver.direct.direct_seeds` of ``receivers`` from the shooting's own walk
        (its rays were cast and counted by the shooting)."""
        receivers = np.asarray(receivers, np.int64)
        return pick_seeds([self.walk[int(r)] for r in receivers], receivers, self.rays_launched, 0,
                          config or TracerConfig())


#: The walk's records when there is no walk: (0, 0) arrays and a launch offset.
_NO_WALK = build(WalkRecords, miss=np.zeros((0, 0)), events=np.zeros((0, 0), np.int32),
                 hist=np.zeros((0, 0), np.int32), src_base=0)


@dataclass
class _Context:
    """The shooting's constant inputs: the records :func:`raytrace.engine.kernels.bounce` takes."""

    scene: ShotScene
    media: ShotMedia
    receivers: ShotReceivers
    settings: ShotSettings
    walk: bool  # the refraction-only walk rides on the shooting's rays


def _take(rays: ShotRays, index) -> ShotRays:
    """The rays ``index`` (a slice or indices) of ``rays``, C-contiguous as the kernel needs."""
    return ShotRays(*(a[index] for a in rays))


def _concat(parts: list[ShotRays]) -> ShotRays | None:
    if not parts:
        return None
    if len(parts) == 1:
        return parts[0]
    return ShotRays(*(np.concatenate(arrays) for arrays in zip(*parts)))


@dataclass
class _Log:
    """Event log: one entry per (interacting ray, kind); rays point at their last entry."""

    parent: list = field(default_factory=list)
    code: list = field(default_factory=list)
    face: list = field(default_factory=list)
    size: int = 0


@dataclass
class _Found:
    rx: list = field(default_factory=list)
    hist: list = field(default_factory=list)
    n: list = field(default_factory=list)
    src: list = field(default_factory=list)
    close: list = field(default_factory=list)
    codes: list = field(default_factory=list)  # resolved per launch batch
    faces: list = field(default_factory=list)


def _context(scene: TracerScene, media: MediaTable, rx_m: np.ndarray, rx_medium: np.ndarray, kmax: int,
             dynamic_range_db: float, walk: bool = False, config: TracerConfig | None = None) -> _Context:
    """The shooting's constant inputs, in the dtypes :func:`raytrace.engine.kernels.bounce` is compiled for:
    geometry in float32 in the scene's centred frame, the power attenuation constant
    ``alpha = k0 |Im n|`` [Np/m] of every medium at the centre frequency."""
    config = config or TracerConfig()
    rx_medium = np.asarray(rx_medium, np.int64)
    tables = media.kernel_tables
    alpha = (2.0 * np.pi * media.frequencies_hz[0] / C0) * -media.n[0].imag
    zone = zones(media)
    need = _interactions_needed(media, rx_medium)
    shot = scene.shot_tables
    rx32 = np.ascontiguousarray((np.asarray(rx_m, float) - scene.center).astype(np.float32))
    no_passes = not scene.has_transparent(tables.transparent)
    return _Context(
        scene=shot,
        media=build(ShotMedia, parent=tables.parent, material_class=tables.material_class,
                    transparent=tables.transparent, n_real=media.n_real.astype(np.float32),
                    alpha=alpha.astype(np.float32), zone=zone, need=need,
                    return_m=return_lengths(scene, media, zone, need, alpha),
                    bounds_m=scene.tables.bounds32),
        receivers=build(ShotReceivers, position_m=rx32,
                        zone=np.ascontiguousarray(zone[rx_medium + 1]),
                        **receiver_grid(rx32)),
        settings=build(ShotSettings, threshold=10.0 ** (-dynamic_range_db / 10.0), kmax=int(kmax),
                       reception_factor=config.reception_factor, curvature_margin=config.curvature_margin,
                       no_passes=no_passes, walk_events=config.walk_max_events),
        walk=bool(walk),
    )


def receiver_grid(rx32: np.ndarray) -> dict:
    """A uniform grid over the receivers (the :class:`~raytrace.engine.records.ShotReceivers` grid
    fields): cells of about one receiver each (at most 32 per axis), receivers listed cell by
    cell. :func:`raytrace.engine.kernels.bounce` tests a ray segment only against the receivers
    of the cells its bounding box, widened by the largest tube half-width along it, overlaps:
    a receiver outside that box is farther than the half-width from every point of the segment,
    so the receptions are those of testing every receiver (exact), at a cost that no longer
    grows with the receivers far from the ray. Cell indices are ``floor((x - lo) / cell)`` in
    float64, clipped, here and in the kernel alike (monotonic: a receiver inside the box lies
    in a cell of the box's index range)."""
    p = np.asarray(rx32, np.float64).reshape(-1, 3)
    if len(p) == 0:
        return {"grid_lo_m": np.zeros(3), "grid_cell_m": 1.0, "grid_dims": np.ones(3, np.int64),
                "cell_start": np.zeros(2, np.int64), "cell_items": np.zeros(0, np.int64)}
    lo, hi = p.min(axis=0), p.max(axis=0)
    extent = np.maximum(hi - lo, 1e-3)
    cell = max(float(np.prod(extent) / len(p)) ** (1.0 / 3.0), float(extent.max()) / 32.0, 1e-3)
    dims = np.clip(np.ceil(extent / cell).astype(np.int64), 1, 32)
    idx = np.clip(np.floor((p - lo) / cell).astype(np.int64), 0, dims - 1)
    flat = (idx[:, 0] * dims[1] + idx[:, 1]) * dims[2] + idx[:, 2]
    order = np.argsort(flat, kind="stable")
    start = np.zeros(int(np.prod(dims)) + 1, np.int64)
    np.add.at(start, flat + 1, 1)
    return {"grid_lo_m": lo, "grid_cell_m": cell, "grid_dims": dims, "cell_start": np.cumsum(start),
            "cell_items": order.astype(np.int64)}


def _bounce(ctx: _Context, rays: ShotRays, log: _Log, found: _Found, walk: WalkRecords = _NO_WALK
            ) -> "tuple[int, ShotRays | None]":
    """Cast one chunk of live rays, record receptions, and spawn the next generation
    (the per-ray work is :func:`raytrace.engine.kernels.bounce`); returns the rays cast and the
    children."""
    cast, children, entries, got = kernels.bounce(rays, ctx.scene, ctx.media, ctx.receivers, ctx.settings, walk,
                                                  log.size)
    if len(got.rx):
        for name, value in zip(("rx", "hist", "n", "src", "close"), got):
            getattr(found, name).append(value)
    if len(entries.parent):
        log.parent.append(entries.parent)
        log.code.append(entries.code)
        log.face.append(entries.face)
        log.size += len(entries.parent)
    if len(children.o) == 0:
        return cast, None
    return cast, children


def shoot(
    scene: TracerScene,
    media: MediaTable,
    tx_m: np.ndarray,
    tx_medium: int,
    rx_m: np.ndarray,
    rx_medium: np.ndarray,
    rays: int,
    max_interactions: int,
    dynamic_range_db: float,
    budget: Budget | None = None,
    walk: bool = False,
    pool: Executor | None = None,
    config: TracerConfig | None = None,
) -> Candidates:
    """Launch ``rays`` directions, bounce them, return reception candidates (vectorised per bounce).
    ``walk``: also the refraction-only walk of :func:`raytrace.solver.direct.direct_seeds` on the same
    rays (:attr:`Candidates.walk`; the walk's own launch is this one, batch for batch).

    Per ray the state is position, direction, medium, power factor, tube
    radius/angle, event count, launch index and a pointer into an event log
    (parent event, code, face) from which candidate signatures are rebuilt;
    the spawned origin is offset off the surface just left (float32 safety). Launch batches,
    live-ray cap, threads, chunks and reception: ``config``
    (:class:`~raytrace.solver.config.TracerConfig`); ``pool``: the caller's workers instead of
    ``config.threads`` of its own.
    """
    config = config or TracerConfig()
    max_events = config.walk_max_events
    kmax = int(max_interactions)
    width = max(kmax, 1)
    ctx = _context(scene, media, rx_m, rx_medium, kmax, dynamic_range_db, walk, config)
    if ctx.walk and not ctx.settings.no_passes:
        raise ValueError("the walk needs a scene without transparent surfaces (raytrace.engine.scene.scene_for)")
    n_rx = len(rx_m)
    max_steps = 4 * kmax + 2 * len(media.materials) + 8
    if ctx.walk:
        max_steps = max(max_steps, max_events + 1)  # a walked ray's generations: one per event
    spacing = angular_spacing_rad(rays)
    tx_c = (np.asarray(tx_m, float) - scene.center).astype(np.float32)

    def launch_batch(first: int) -> tuple[_Found, int, list | None]:
        # the whole bounce tree of one batch of launch directions: bounds memory without
        # culling branches; batches are independent (own event log and candidates)
        count = min(config.launch_batch, rays - first)
        launch = fibonacci_sphere(rays, np.arange(first, first + count))
        log, found, segments, held = _Log(), _Found(), 0, 0
        state = build(
            ShotRays,
            o=np.broadcast_to(tx_c, (count, 3)).copy(),
            d=launch.astype(np.float32),
            med=np.full(count, tx_medium, np.int64),
            w=np.ones(count, np.float32),
            rad=np.zeros(count, np.float32),
            ang=np.full(count, spacing, np.float32),
            length=np.zeros(count, np.float32),
            nint=np.zeros(count, np.int64),
            hist=np.full(count, -1, np.int64),
            src=np.arange(first, first + count),
            mode=np.full(count, 1 if ctx.walk else 0, np.int8),
        )
        records = _NO_WALK
        if ctx.walk:  # closest approach per launch and receiver, its events and last log entry
            records = build(WalkRecords, miss=np.full((count, n_rx), np.inf), events=np.zeros((count, n_rx), np.int32),
                            hist=np.full((count, n_rx), -1, np.int32), src_base=first)
        for _ in range(max_steps):
            n_live = len(state.o)
            if n_live == 0:
                break
            bounced = [
                _bounce(ctx, _take(state, slice(a, a + config.chunk_rays)), log, found, records)
                for a in range(0, n_live, config.chunk_rays)
            ]
            cast = sum(n for n, _c in bounced)
            segments += cast
            state = _concat([c for _n, c in bounced if c is not None])
            if budget is not None:
                budget.charge(cast)
                held = _hold(budget, held, log, found, state, records)
            if state is None:
                break
            if len(state.o) > config.max_live_rays:
                # safety cap: keep the rays most likely to matter, power factor over the squared
                # reduced length sum L_i / n_i (the paraxial ray-tube spreading of layered media)
                priority = state.w / np.maximum(state.length, 1e-4) ** 2
                priority[state.mode > 0] = np.inf  # the walk's rays (no reflection yet): one per launch at most
                cap = config.max_live_rays
                keep = np.sort(np.argpartition(-priority, cap - 1)[:cap])
                state = _take(state, keep)
        offers = None
        entries = _log_arrays(log)
        if ctx.walk:
            miss, n_ev, last = records.miss, records.events, records.hist
            offers = closest_launches(
                miss, n_ev, lambda rows, c: _signatures(entries, last[rows, c], n_ev[rows, c], max_events)[0], launch,
                config.seeds_per_receiver)
        _resolve(found, log, entries, width)  # signatures of this batch's candidates; the log is freed
        if budget is not None:  # what this batch leaves behind: its candidates
            held = _hold(budget, held, log, found, None, _NO_WALK)
        return found, segments, offers, held

    firsts = list(range(0, rays, config.launch_batch))
    workers = min(config.threads, len(firsts))
    if pool is not None:  # the caller's workers (raytrace.solver.tracer queues other work beside)
        batches = list(pool.map(launch_batch, firsts))
    elif workers > 1:
        # Embree and the large numpy operations release the GIL: batches run concurrently;
        # the results are merged in batch order, so the candidates are those of a serial run
        with ThreadPoolExecutor(max_workers=workers) as pool:
            batches = list(pool.map(launch_batch, firsts))
    else:
        batches = [launch_batch(first) for first in firsts]
    found = _Found()
    for part, _n, _o, _h in batches:
        for name in ("rx", "n", "src", "close", "codes", "faces"):
            getattr(found, name).extend(getattr(part, name))
    segments = sum(n for _f, n, _o, _h in batches)
    batch_bytes = sum(h for _f, _n, _o, h in batches)
    walked = None
    if ctx.walk:
        walked = [[] for _ in range(n_rx)]
        for _f, _n, offers, _h in batches:
            for pool, offer in zip(walked, offers):
                pool.extend(offer)
    if not found.codes:
        return Candidates(
            receiver=np.zeros(0, np.int64), codes=np.zeros((0, width), np.int64),
            faces=np.zeros((0, width), np.int64), nint=np.zeros(0, np.int64), launch_dir=np.zeros((0, 3)),
            closeness=np.zeros(0), rays_launched=rays, segments=segments, walk=walked,
        )
    if budget is not None:  # the merged candidates replace the batches' parts (C rows of 6 + 2 K numbers)
        budget.hold(sum(len(x) for x in found.rx) * (6 + 2 * width) * 8)
        budget.release(batch_bytes)
    return Candidates(
        receiver=np.concatenate(found.rx),
        codes=np.concatenate(found.codes),
        faces=np.concatenate(found.faces),
        nint=np.concatenate(found.n),
        launch_dir=fibonacci_sphere(rays, np.concatenate(found.src)),
        closeness=np.concatenate(found.close),
        rays_launched=rays,
        segments=segments,
        walk=walked,
    )


def zones(media: MediaTable) -> np.ndarray:
    """Per medium (index m + 1): its zone, the connected region of one material it belongs to.

    A ray only ever crosses a surface of organ X between X and its parent, and the surfaces
    between identical materials are not in the shooting's scene (transparent): so the media a
    ray can be in without an interaction are those joined by organ/parent pairs of the same
    material class, and a zone is a connected component of that graph (labels are the smallest
    medium index + 1 of the component). Two organs of one material that do not touch (two
    separate bowel loops, the air of a closed room and the air outside its walls) are different
    zones: a ray in one never reaches a point of the other without an interaction."""
    cls = np.asarray(media.material_class, np.int64)
    label = np.arange(len(cls), dtype=np.int64)

    def root(a: int) -> int:
        while label[a] != a:
            a = int(label[a])
        return a

    for organ, parent in enumerate(np.asarray(media.parent, np.int64)):
        a, b = organ + 1, int(parent) + 1
        if cls[a] == cls[b]:
            ra, rb = root(a), root(b)
            label[max(ra, rb)] = min(ra, rb)
    return np.array([root(a) for a in range(len(cls))], np.int64)


def return_lengths(scene: TracerScene, media: MediaTable, zone: np.ndarray, need: np.ndarray,
                   alpha: np.ndarray) -> np.ndarray:
    """(F, 2) float32: for a ray on the inside (column 0) / outside (1) of face f's organ, in a
    zone (:func:`zones`) from which no receiver is reached without an interaction, the least
    length it must still travel in that zone's medium before it can cross towards a receiver.

    The zones form a tree (the containment tree with the surfaces between identical materials
    contracted). From zone Z a receiver can be reached only through a face to a neighbour Y
    whose side of the tree (without Z) holds a receiver's zone: Z's *exit* faces. A ray on an
    exit face needs no length (0). A ray on any other face of Z must reach an exit face, or
    leave Z and come back through a non-exit face (its side of the tree has no receiver), so
    it travels at least D_Z, the least distance between Z's non-exit and exit faces, in Z:
    bounded below by the least distance between their bounding boxes
    (:func:`raytrace.engine.boxgap.least_gap`, exact, in O(n log n) time). When every exit face is
    on one convex organ that Z surrounds, a ray leaving that organ's surface into Z cannot meet it again before it has
    reached another face of Z: it travels at least twice D_Z. Only absorbing zones
    (``alpha > 0``) get a bound.
    The shooting drops a ray whose power factor times ``exp(-2 alpha L)`` over that length is
    below the dynamic range (:func:`raytrace.engine.kernels._may_return`): exact, since power
    factors only decrease. In a closed room of 1 m concrete walls at 3.5 GHz (alpha 3.8 Np/m)
    a ray reflected at the walls' outer face must cross the 1 m back, -66 dB: the steep ones
    are dropped there instead of being cast.

    The table depends on the faces and on which zones hold a receiver and absorb, not on the
    request otherwise: it is made once per phantom and such a pattern
    (:meth:`raytrace.engine.scene.FaceTables.cached`; at 0.98 M triangles it took 2 s per request)."""
    parent = np.asarray(media.parent, np.int64)
    zone = np.asarray(zone, np.int64)
    need = np.asarray(need, np.int64)
    key = ("return_lengths", parent.tobytes(), zone.tobytes(), need.tobytes(), (np.asarray(alpha) > 0.0).tobytes())
    return scene.tables.cached(key, lambda: _return_lengths(scene, parent, zone, need, alpha))


def _return_lengths(scene: TracerScene, parent: np.ndarray, zone: np.ndarray, need: np.ndarray,
                    alpha: np.ndarray) -> np.ndarray:
    """:func:`return_lengths`, computed."""
    out = np.zeros((len(scene.face_organ), 2), np.float32)
    organ = np.asarray(scene.face_organ, np.int64)
    z_in, z_out = zone[organ + 1], zone[parent[organ] + 1]
    n_zone = len(zone)
    # the zone tree rooted at the outside's zone: parent zone and receivers below each zone
    up = np.full(n_zone, -1, np.int64)
    for o, p in enumerate(parent):
        a, b = int(zone[o + 1]), int(zone[p + 1])
        if a != b:
            up[a] = b
    below = np.zeros(n_zone, np.int64)
    below[np.unique(zone[need == 0])] = 1  # receivers' zones (need 0)
    total = int(below.sum())
    order = []  # zones from the leaves up (a zone's children before it)
    depth = np.zeros(n_zone, np.int64)
    for z in range(n_zone):
        w = z
        while up[w] >= 0:
            depth[z] += 1
            w = int(up[w])
    for z in sorted(set(int(x) for x in zone), key=lambda x: -depth[x]):
        order.append(z)
        if up[z] >= 0:
            below[up[z]] += below[z]

    def exit_towards(z: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Whether a receiver lies on y's side of the tree edge z - y."""
        child = up[y] == z  # y below z
        return np.where(child, below[y] > 0, total - below[z] > 0)

    def boxes(rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        tri = scene.vertices[scene.faces[rows]]
        return tri.min(axis=1), tri.max(axis=1)

    for z in np.unique(zone):
        m = int(np.flatnonzero(zone == z)[0])
        if need[m] == 0 or not alpha[m] > 0.0 or need[m] >= 1 << 20:
            continue
        sides = []  # (faces, column, exit?) of Z's faces seen from Z
        for col, here, there in ((0, z_in, z_out), (1, z_out, z_in)):
            rows = np.flatnonzero((here == z) & (there != z))
            sides.append((rows, col, exit_towards(np.full(len(rows), z), there[rows])))
        exits = np.concatenate([rows[ex] for rows, _c, ex in sides])
        others = [(rows[~ex], col) for rows, col, ex in sides]
        if len(exits) == 0 or sum(len(r) for r, _c in others) == 0:
            continue
        lo_e, hi_e = boxes(exits)
        lo_o, hi_o = boxes(np.concatenate([r for r, _c in others]))
        gap = least_gap(lo_o, hi_o, lo_e, hi_e)
        for rows, col in others:
            out[rows, col] = np.float32(gap * (1.0 - 1e-4))  # rounded down: a lower bound in float32
        # all exits on one convex organ C around which Z lies (a room's air in its walls): a ray
        # leaving C's surface into Z never meets C again without first reaching another face of
        # Z, and must then come back: twice the gap
        inner_exits, outer_exits = sides[0][0][sides[0][2]], sides[1][0][sides[1][2]]
        if len(inner_exits) == 0:
            exit_organs = np.unique(organ[outer_exits])
            if len(exit_organs) == 1 and _convex(scene, int(exit_organs[0])):
                out[outer_exits, 1] = np.float32(2.0 * gap * (1.0 - 1e-4))
    return out


def _convex(scene: TracerScene, organ: int, max_faces: int = 5_000) -> bool:
    """Whether ``organ``'s closed, outward-oriented mesh is convex: every vertex of it on the
    inner side of every face's plane (to 1e-9 of its size). Larger meshes: False (no claim)."""
    rows = np.flatnonzero(np.asarray(scene.face_organ) == organ)
    if len(rows) == 0 or len(rows) > max_faces:
        return False
    verts = scene.vertices[np.unique(scene.faces[rows])]
    normals = scene.face_normals[rows]
    offsets = np.einsum("ij,ij->i", normals, scene.vertices[scene.faces[rows, 0]])
    size = float(np.ptp(verts, axis=0).max())
    return bool((verts @ normals.T - offsets[None, :] <= 1e-9 * size).all())


def _interactions_needed(media: MediaTable, rx_medium: np.ndarray) -> np.ndarray:
    """Per medium (index m + 1): the fewest interactions a ray in it needs before it can be
    received, i.e. the number of transmissions to reach a receiver's zone (:func:`zones`; 0 in
    those zones; a large number when none can be reached).

    A ray only ever crosses a surface of organ X between X and its parent (the bounce
    requires the side it comes from to be the ray's), each crossing of a visible surface costs
    one interaction and joins two zones, and reception needs the ray to be in the receiver's
    zone (a ray in another region of the same material never passes the receiver without
    crossing a surface). So a breadth-first search over the graph of zones (an edge per
    organ/parent pair of different materials) bounds the interactions still needed; a ray with
    ``nint + need > max_interactions`` can never make a candidate and is not spawned (exact
    pruning). By zone rather than by material: in a closed room, rays leaving the walls into
    the air outside need two more crossings, not none."""
    zone = zones(media)
    cls = np.asarray(media.material_class, np.int64)
    n_zone = len(zone)
    adjacent: list[set[int]] = [set() for _ in range(n_zone)]
    for organ, parent in enumerate(np.asarray(media.parent, np.int64)):
        a, b = int(zone[organ + 1]), int(zone[parent + 1])
        if cls[organ + 1] != cls[parent + 1]:
            adjacent[a].add(b)
            adjacent[b].add(a)
    big = 1 << 20
    dist = np.full(n_zone, big, np.int64)
    frontier = sorted({int(z) for z in zone[np.asarray(rx_medium, np.int64) + 1]})
    dist[frontier] = 0
    step = 0
    while frontier:  # a graph of a few dozen zones
        step += 1
        nxt = sorted({b for a in frontier for b in adjacent[a] if dist[b] == big})
        dist[nxt] = step
        frontier = nxt
    return dist[zone]


def _nbytes(parts) -> int:
    return sum(a.nbytes for a in parts)


def _hold(budget: Budget, held: int, log: _Log, found: _Found, state: ShotRays | None, records) -> int:
    """Tell ``budget`` what one launch batch holds now (event log, reception candidates, live
    rays, walk records) given that ``held`` bytes were accounted before; returns the new figure."""
    now = (_nbytes(log.parent) + _nbytes(log.code) + _nbytes(log.face)
           + sum(_nbytes(getattr(found, name)) for name in ("rx", "hist", "n", "src", "close", "codes", "faces"))
           + (0 if state is None else _nbytes(state)) + _nbytes(records[:3]))
    budget.hold(now - held)
    return now


def _log_arrays(log: _Log) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The event log as three arrays: parent entry, code, face."""
    return tuple(np.concatenate(part) if part else np.zeros(0, np.int32) for part in (log.parent, log.code, log.face))


def _signatures(log: tuple, last: np.ndarray, n: np.ndarray, width: int) -> tuple[np.ndarray, np.ndarray]:
    """Signatures (codes, faces; (len(last), width), -1 padded) of rays whose last event is log
    entry ``last`` (-1: none) after ``n`` events, rebuilt by walking the event log (its
    :func:`_log_arrays`) back."""
    parent_log, code_log, face_log = log
    codes = np.full((len(last), width), -1, np.int64)
    faces = np.full((len(last), width), -1, np.int64)
    slot = np.asarray(n, np.int64) - 1
    cur = np.asarray(last, np.int64).copy()
    while True:
        rows = np.flatnonzero(cur >= 0)
        if len(rows) == 0:
            break
        codes[rows, slot[rows]] = code_log[cur[rows]]
        faces[rows, slot[rows]] = face_log[cur[rows]]
        slot[rows] -= 1
        cur[rows] = parent_log[cur[rows]]
    return codes, faces


def _resolve(found: _Found, log: _Log, entries: tuple, width: int) -> None:
    """Rebuild the signatures (codes, faces) of the candidates found since the last call
    (:func:`_signatures`, from the log's :func:`_log_arrays` ``entries``), then empty the log."""
    new = slice(len(found.codes), len(found.hist))
    hist = found.hist[new]
    if hist:
        codes, faces = _signatures(entries, np.concatenate(hist), np.concatenate(found.n[new]), width)
        # one resolved block per found block, so later batches index consistently
        sizes = [len(x) for x in hist]
        cuts = np.cumsum(sizes)[:-1]
        found.codes.extend(np.split(codes, cuts))
        found.faces.extend(np.split(faces, cuts))
    log.parent.clear()
    log.code.clear()
    log.face.clear()
    log.size = 0
