"""A channel request as a gprMax FDTD model (docs/validation.md, "The FDTD model").

:func:`build_model` turns a :class:`raytrace.ChannelSpec` (the body of ``POST /v1/channel``)
into the text of a gprMax 4 input file:

* **Domain.** The box around the transmitter and receivers grown by ``margin_m`` on every
  side (or ``bounds_m``), in cubic cells of ``cell_m``: the phantom's media on it come from
  :func:`raytrace.body.voxels.voxelize` (a cell takes the medium at its centre; surfaces move
  by up to sqrt(3)/2 cells). Where the box reaches past the phantom the margin is air; where
  it cuts through tissue, the tissue runs on into the absorbing layer, so a cut body is an
  unbounded one there (the truncation is stated, never hidden).
* **Absorbing boundaries.** ``pml_cells`` cells of gprMax's CFS-PML outside that box, filled
  by continuing the edge cells' media (a matched termination of lossy tissue).
* **Media.** Each distinct material is fitted by Debye poles over ``fit_band_hz``
  (:mod:`fullwave.debye`, fit error reported); air is gprMax's ``free_space``. The cells are
  covered by boxes (sorted, so the text is a function of the grid alone) with gprMax's material
  averaging on, dispersive media included (``#dispersive_averaging: y``): an E edge between
  cells of different media takes their arithmetic mean, the usual second-order treatment of
  an interface on cell faces (exact for the tangential field of a planar layer). Without it an
  edge on an interface took the medium of whichever box gprMax wrote last, so a 2 mm skin was
  one or two E-nodes thick depending on the box order, and contact sensors moved by up to
  0.85 dB between two boxes around the same antennas (docs/validation.md, "The FDTD model").
* **Source.** A Hertzian dipole (``I dl``, ``dl`` = one cell) per non-zero Cartesian
  component of the transmitter's polarization, amplitudes the components, driven by a
  Ricker pulse centred on the carrier (spectrum over ~0.1-2.5 f0). Receivers record Ex, Ey,
  Ez. Both are snapped to the Yee node of their dominant field component; the snapped
  positions are what the tracer is compared at (:mod:`fullwave.compare`); the other
  components sit up to half a cell from it.
* **Pulse.** gprMax's ``gaussiandotnorm`` at the carrier (a differentiated Gaussian: no DC, its
  spectrum peaks at f0 / sqrt(2) and is within 10 dB over ~0.1-2 f0), which lasts 2 / f0.
* **Time window.** The pulse (2 / f0) plus 1.3 times the slowest direct travel time (largest
  Re n of the domain's media times the farthest receiver's distance) plus 1.5 ns: lossy tissue
  leaves nothing later worth the iterations (the report shows the field's last-10 % energy).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from raytrace.body.phantom import Phantom
from raytrace.body.voxels import voxelize
from raytrace.physics.em import C0
from raytrace.spec import ChannelSpec

from .debye import DebyeFit, fit_debye

#: gprMax's Courant factor for 3-D cubic cells: dt = 0.99 * h / (c sqrt(3)) (its default stability margin).
COURANT = 0.99


@dataclass(frozen=True)
class FdtdOptions:
    """How a request becomes an FDTD model. Lengths in metres."""

    cell_m: float = 0.002
    margin_m: float = 0.02
    pml_cells: int = 10
    bounds_m: np.ndarray | None = None
    fit_band_hz: tuple[float, float] | None = None  # default (0.5 f0, 2 f0)
    poles: int = 2
    time_window_s: float | None = None

    def __post_init__(self) -> None:
        if not (np.isfinite(self.cell_m) and 1e-4 <= self.cell_m <= 0.02):
            raise ValueError(f"cell_m must be in [1e-4, 0.02] m, got {self.cell_m}")
        if not (np.isfinite(self.margin_m) and 0.0 <= self.margin_m <= 0.5):
            raise ValueError(f"margin_m must be in [0, 0.5] m, got {self.margin_m}")
        if not 4 <= int(self.pml_cells) <= 40:
            raise ValueError(f"pml_cells must be in [4, 40], got {self.pml_cells}")


@dataclass
class FdtdModel:
    """A gprMax input and what it was built from."""

    input_text: str
    spec: ChannelSpec
    options: FdtdOptions
    dt_s: float
    iterations: int
    cells: tuple[int, int, int]  # including the PML
    origin_m: np.ndarray  # world position of the gprMax domain's (0, 0, 0)
    tx_m: np.ndarray  # snapped transmitter (its dominant component's Yee node)
    rx_m: np.ndarray  # (R, 3) snapped receivers
    rx_names: tuple[str, ...]
    tx_components: dict[str, float]  # axis -> dipole amplitude (the polarization's components)
    materials: dict[str, DebyeFit] = field(default_factory=dict)  # gprMax id -> fit
    boxes: int = 0
    #: per receiver, the media (organ names, "air") of the cells that share its node's edge: the
    #: grid's view of where it is (a contact sensor in a 2 mm skin can sit on fat or air cells)
    rx_cell_media: tuple[tuple[str, ...], ...] = ()


_AXES = "xyz"


def _node(pos: np.ndarray, pol: np.ndarray, origin: np.ndarray, h: float) -> tuple[np.ndarray, np.ndarray]:
    """Cell index and world position of the Yee node of ``pol``'s dominant component nearest ``pos``."""
    a = int(np.argmax(np.abs(pol)))
    offset = np.zeros(3)
    offset[a] = 0.5 * h
    idx = np.round((pos - offset - origin) / h).astype(np.int64)
    return idx, origin + idx * h + offset


def _edge_cells(organ: np.ndarray, idx: np.ndarray, pol: np.ndarray) -> set[int]:
    """Organ indices (-1: air) of the four cells sharing the Yee edge of ``pol``'s dominant
    component at node ``idx`` (the edge runs along that axis from ``idx``; the cells lie at
    ``idx - 1`` and ``idx`` on the two other axes)."""
    a = int(np.argmax(np.abs(pol)))
    ranges = [range(int(i) - 1, int(i) + 1) if ax != a else range(int(i), int(i) + 1) for ax, i in enumerate(idx)]
    return {int(organ[i, j, k]) for i in ranges[0] for j in ranges[1] for k in ranges[2]}


def _boxes(organ: np.ndarray) -> list[tuple[int, int, int, int, int, int, int]]:
    """Cover the non-air cells of ``organ`` by boxes (i0, j0, k0, i1, j1, k1, medium), exclusive
    upper ends: runs along x, merged over y where a row repeats, then over z where a layer does."""
    nx, ny, nz = organ.shape
    layers = []
    for k in range(nz):
        rects: list[list[int]] = []  # [i0, i1, j0, j1, m]
        open_: dict[tuple[int, int, int], list[int]] = {}
        for j in range(ny):
            row = organ[:, j, k]
            edges = np.flatnonzero(np.diff(row)) + 1
            starts = np.concatenate([[0], edges])
            ends = np.concatenate([edges, [nx]])
            runs = {(int(s), int(e), int(row[s])) for s, e in zip(starts, ends) if row[s] >= 0}
            nxt = {}
            for key in runs:
                r = open_.get(key)
                if r is not None and r[3] == j:
                    r[3] = j + 1
                else:
                    r = [key[0], key[1], j, j + 1, key[2]]
                    rects.append(r)
                nxt[key] = r
            open_ = nxt
        layers.append({tuple(r) for r in rects})
    out = []
    live: dict[tuple, list[int]] = {}
    for k, rects in enumerate(layers):
        nxt = {}
        for r in rects:
            b = live.get(r)
            if b is not None and b[1] == k:
                b[1] = k + 1
            else:
                b = [k, k + 1, r]
                out.append(b)
            nxt[r] = b
        live = nxt
    return [(r[0], r[2], k0, r[1], r[3], k1, r[4]) for k0, k1, r in out]


def _domain(spec: ChannelSpec, resolved, options: FdtdOptions) -> tuple[np.ndarray, np.ndarray]:
    """The model's box without the PML: ``options.bounds_m``, or the antennas' box grown by ``margin_m``."""
    if options.bounds_m is not None:
        lo, hi = np.asarray(options.bounds_m, float).reshape(2, 3)
        return lo, hi
    pts = np.vstack([resolved.tx_m[None, :], resolved.rx_m])
    return pts.min(axis=0) - options.margin_m, pts.max(axis=0) + options.margin_m


def _time_window(spec: ChannelSpec, resolved, n_max: float, options: FdtdOptions) -> tuple[float, float, int]:
    """(window [s], dt [s], iterations) for media whose largest Re n is ``n_max`` (module docstring)."""
    f0 = spec.frequency_hz
    dist = float(np.max(np.linalg.norm(resolved.rx_m - resolved.tx_m, axis=1)))
    window = options.time_window_s or (2.0 / f0 + 1.3 * n_max * dist / C0 + 1.5e-9)
    dt = COURANT * options.cell_m / (C0 * np.sqrt(3.0))
    return window, dt, int(np.ceil(window / dt)) + 1


@dataclass(frozen=True)
class ModelSize:
    """A model's cells (PML included) and time steps, known before it is built."""

    cells: tuple[int, int, int]
    iterations: int

    @property
    def cell_updates(self) -> int:
        """Cells x time steps: the FDTD's work (its wall time is about proportional to it)."""
        return int(np.prod(self.cells)) * self.iterations

    @property
    def memory_bytes(self) -> int:
        """An upper bound on gprMax's memory for the model: :data:`GPRMAX_BYTES_PER_CELL` per cell plus
        :data:`GPRMAX_OVERHEAD_BYTES`."""
        return int(np.prod(self.cells)) * GPRMAX_BYTES_PER_CELL + GPRMAX_OVERHEAD_BYTES


#: gprMax's memory per cell, bounded: its own estimate ("Memory used") was 183 B per cell for the
#: torso slice at 1.5 mm (6.4e5 cells, five two-pole media averaged at interfaces) and 252 B for the
#: layered case at 2 mm (2.7e5 cells, more of them PML), beyond a fixed ~65 MB; 400 B leaves room
#: for more poles where several media meet.
GPRMAX_BYTES_PER_CELL = 400
#: ... plus this for the interpreter and gprMax's own arrays (measured ~65 MB).
GPRMAX_OVERHEAD_BYTES = 100 * 1024**2


def model_size(spec: ChannelSpec, phantom: Phantom, options: FdtdOptions = FdtdOptions()) -> ModelSize:
    """The size of :func:`build_model`'s model without voxelizing or fitting anything: the same
    domain and grid shape (the voxel grid's ``ceil(extent / cell)`` per axis, plus the PML), and
    an upper bound on the time steps (the slowest medium of the whole phantom at the carrier, where
    the model takes the slowest of the media inside its box). A service bounds a job's work with it
    before the job is accepted. The bound takes Re n of the Cole-Cole model 1 % up: the Debye fit
    the model uses is within 0.3 % of it in permittivity (:mod:`fullwave.debye`)."""
    resolved = spec.resolve(phantom)
    lo, hi = _domain(spec, resolved, options)
    h = float(options.cell_m)
    shape = np.maximum(np.ceil((hi - lo) / h).astype(np.int64), 1) + 2 * int(options.pml_cells)
    materials = [spec.homogeneous] if spec.homogeneous is not None else [o.material for o in phantom.organs]
    f0 = np.array([spec.frequency_hz])
    n_max = max([1.0] + [1.01 * float(np.sqrt(m.complex_relative_permittivity(f0)[0]).real) for m in materials])
    return ModelSize(cells=tuple(int(c) for c in shape), iterations=_time_window(spec, resolved, n_max, options)[2])


def build_model(spec: ChannelSpec, phantom: Phantom, options: FdtdOptions = FdtdOptions()) -> FdtdModel:
    """The gprMax model of ``spec`` in ``phantom`` (module docstring)."""
    resolved = spec.resolve(phantom)
    h = float(options.cell_m)
    lo, hi = _domain(spec, resolved, options)
    grid = voxelize(phantom, h, bounds_m=np.array([lo, hi]), pad_cells=0)
    organ = grid.organ.astype(np.int64)
    if spec.homogeneous is not None:
        organ = np.where(organ >= 0, 0, -1)
        materials = [spec.homogeneous]
    else:
        materials = [o.material for o in phantom.organs]
    npml = int(options.pml_cells)
    organ = np.pad(organ, npml, mode="edge")
    origin = grid.origin_m - npml * h
    cells = organ.shape
    f0 = spec.frequency_hz
    band = options.fit_band_hz or (0.5 * f0, 2.0 * f0)
    # one gprMax material per distinct medium
    ids: dict[str, str] = {}
    fits: dict[str, DebyeFit] = {}
    medium_id = np.empty(len(materials), object)
    for m, mat in enumerate(materials):
        key = mat.label
        if key not in ids:
            ids[key] = f"m{len(ids)}_" + "".join(c if c.isalnum() else "_" for c in key)[:40]
            fits[ids[key]] = fit_debye(mat, band, options.poles)
        medium_id[m] = ids[key]
    used = sorted(set(int(v) for v in np.unique(organ) if v >= 0))
    # snapped antennas
    tx_idx, tx_m = _node(resolved.tx_m, resolved.tx_polarization, origin, h)
    rx_m = np.array([_node(r, p, origin, h)[1] for r, p in zip(resolved.rx_m, resolved.rx_polarization)])
    rx_idx = [_node(r, p, origin, h)[0] for r, p in zip(resolved.rx_m, resolved.rx_polarization)]
    for name, idx in [("transmitter", tx_idx)] + [(f"receivers[{i}]", x) for i, x in enumerate(rx_idx)]:
        if np.any(idx < npml) or np.any(idx >= np.array(cells) - npml):
            raise ValueError(f"{name} lies in or outside the absorbing layer; grow margin_m or bounds_m")
    # time window
    n_max = max([1.0] + [float(np.sqrt(fits[medium_id[m]].permittivity(f0)).real) for m in used])
    window, dt, iterations = _time_window(spec, resolved, n_max, options)

    lines = [f"#title: CapsuleRT fullwave export of phantom {spec.phantom} at {f0:g} Hz",
             f"#domain: {cells[0] * h:.9g} {cells[1] * h:.9g} {cells[2] * h:.9g}",
             f"#dx_dy_dz: {h:.9g} {h:.9g} {h:.9g}",
             f"#time_window: {window:.9g}",
             f"#pml_cells: {npml}",
             "#dispersive_averaging: y"]
    for m in used:
        mid = medium_id[m]
        fit = fits[mid]
        line = f"#material: {fit.eps_inf:.9g} {fit.sigma_s_per_m:.9g} 1 0 {mid}"
        if line not in lines:
            lines.append(line)
            if fit.delta_eps:
                poles = " ".join(f"{d:.9g} {t:.9g}" for d, t in zip(fit.delta_eps, fit.tau_s))
                lines.append(f"#add_dispersion_debye: {len(fit.delta_eps)} {poles} {mid}")
    boxes = sorted(_boxes(organ))
    for i0, j0, k0, i1, j1, k1, m in boxes:
        lines.append(f"#box: {i0 * h:.9g} {j0 * h:.9g} {k0 * h:.9g} {i1 * h:.9g} {j1 * h:.9g} {k1 * h:.9g} "
                     f"{medium_id[m]} y")
    components = {}
    for a, c in zip(_AXES, resolved.tx_polarization):
        if abs(c) > 1e-12:
            components[a] = float(c)
            lines.append(f"#waveform: gaussiandotnorm {c:.12g} {f0:.9g} w_{a}")
            x, y, z = tx_idx * h
            lines.append(f"#hertzian_dipole: {a} {x:.9g} {y:.9g} {z:.9g} w_{a}")
    names = tuple(r.name for r in spec.receivers)
    for i, idx in enumerate(rx_idx):
        x, y, z = idx * h
        lines.append(f"#rx: {x:.9g} {y:.9g} {z:.9g} rx{i} Ex Ey Ez")
    kept = {medium_id[m]: fits[medium_id[m]] for m in used}
    names_of = [o.name for o in phantom.organs]
    cell_media = tuple(tuple(sorted("air" if m < 0 else names_of[m] for m in _edge_cells(organ, idx, p)))
                       for idx, p in zip(rx_idx, resolved.rx_polarization))
    return FdtdModel(input_text="\n".join(lines) + "\n", spec=spec, options=options, dt_s=dt, iterations=iterations,
                     cells=tuple(int(c) for c in cells), origin_m=origin, tx_m=tx_m, rx_m=rx_m, rx_names=names,
                     tx_components=components, materials=kept, boxes=len(boxes),
                     rx_cell_media=cell_media)


__all__ = ["FdtdModel", "FdtdOptions", "ModelSize", "build_model", "model_size"]
