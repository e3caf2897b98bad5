"""Full-wave (gprMax) cross-checks of the tracer beyond the test suite's homogeneous case: planar
layered walls (the layered, lateral, wall and deep cases) and a transverse slice of the default torso
(docs/validation.md, "Results"). Each case is minutes of CPU per cell size.

    python -m bench.fullwave layered [--out bench/results/fullwave/layered] [--cell-mm 2] [--coarse-factor 0.75]
    python -m bench.fullwave lateral      # contact sensors 0-55 mm off the normal
    python -m bench.fullwave wall         # capsule in small intestine under muscle / 10 mm fat / skin, contact and air
    python -m bench.fullwave deep30       # capsule 30 mm deep in muscle, contact sensors 0-40 deg off the normal
    python -m bench.fullwave deep100      # ... 100 mm deep
    python -m bench.fullwave torso
    python -m bench.fullwave homogeneous  # the test suite's muscle case (5 and 10 cm)
    python -m bench.fullwave table [--reuse]   # every case at its two cell sizes -> the table of docs/validation.md
    python -m bench.fullwave layered --export-only      # the gprMax inputs and the case, no run
    python -m bench.fullwave layered --reuse            # rebuild the report from finished runs

Each writes ``report.json`` and ``report.md`` (:func:`fullwave.run.compare`) in ``--out``.
"""

from __future__ import annotations

import numpy as np

from fullwave.model import FdtdOptions
from raytrace.body.phantom import Organ, Phantom
from raytrace.body.shapes import box
from raytrace.body.torso import contact_point, default_torso
from raytrace.physics.materials import Material
from raytrace.physics.tissues import DEFAULT_FAT
from raytrace.spec import Antenna, ChannelSpec

F0_HZ = 402e6

#: The layered case of issue 23: skin on y in [0, 2] mm, fat [2, 22] mm, muscle beyond; air at y < 0.
SKIN_M = 0.002
FAT_M = 0.020
#: Transmitter depth behind the fat/muscle interface [m].
TX_DEPTH_M = 0.030
#: Lateral half-size of the slabs [m]: far beyond any FDTD box (the box cuts them; docs/validation.md).
HALF_M = 1.0
#: Interactions of the planar cases' traces. A contact sensor's field is a series of reverberations in
#: the 2 mm skin, the fat and the muscle wall; against the exact layered field (layered_exact.py) on the
#: wall case, 6 interactions (the request's default) give +0.43 dB / +48 ps over the capsule and +1.29 dB
#: / +48 ps 45 deg aside, 12 give +0.03 dB / +14 ps and -0.03 dB / +15 ps (docs/validation.md,
#: "The exact layered field as a second reference").
LAYERED_INTERACTIONS = 12


def stack_phantom(layers, name: str) -> Phantom:
    """Nested boxes, planar layers: ``layers`` = (organ, tissue, front face y [m]) from the outside
    in, air at y < 0; each box reaches ``HALF_M`` (less 10 mm per level) elsewhere, a closed mesh
    whose far faces no ray reaches."""
    organs = []
    for k, (organ, tissue, front) in enumerate(layers):
        h = HALF_M - 0.010 * k
        organs.append(Organ(organ, Material(tissue=tissue), box([-h, front, -h], [h, h, h])))
    text = " / ".join(f"{o} from {f * 1e3:g} mm" for o, _, f in layers)
    return Phantom.build(name, organs, description=f"{text}; air at y < 0")


def on_grid(layers, name: str, cell_m: float) -> Phantom:
    """The stack as a grid of ``cell_m`` aligned with y = 0 sees it: each interface on the cell face
    nearest it (a cell takes the medium at its centre; a face at x.5 cells goes up)."""
    return stack_phantom([(o, t, round(f / cell_m + 1e-9) * cell_m) for o, t, f in layers], name)


def _layered(skin_m: float = SKIN_M, fat_m: float = FAT_M):
    return [("skin", "skin_dry", 0.0), ("fat", DEFAULT_FAT, skin_m), ("muscle", "muscle", skin_m + fat_m)]


def layered_phantom(skin_m: float = SKIN_M, fat_m: float = FAT_M) -> Phantom:
    """Skin (skin_dry) from y = 0, fat (infiltrated average) behind it, muscle behind the fat
    (default 2 and 20 mm)."""
    return stack_phantom(_layered(skin_m, fat_m), "layered-fat20")


def layered_on_grid(cell_m: float) -> Phantom:
    """The layered phantom as a grid of ``cell_m`` sees it (3 mm: skin 3, fat 18)."""
    return on_grid(_layered(), "layered-fat20", cell_m)


def _dipole(name: str, position_m) -> Antenna:
    return Antenna(position_m=np.asarray(position_m, float), name=name, polarization=[0, 0, 1], pattern="dipole")


def _aligned_bounds(tx, rxs) -> np.ndarray:
    """20 mm (at least) of margin round every antenna, rounded out to multiples of 6 mm (so that the
    layers' faces are cell faces of the 1.5, 2 and 3 mm grids); 1 nm less at the top, since the
    voxel grid takes ceil(span / cell) cells."""
    pts = np.array([tx] + [r.position_m for r in rxs])
    lo = np.floor((pts.min(axis=0) - 0.02) / 0.006) * 0.006
    hi = np.ceil((pts.max(axis=0) + 0.02) / 0.006) * 0.006 - 1e-9
    return np.array([lo, hi])


def layered_case() -> tuple[ChannelSpec, Phantom, FdtdOptions]:
    """z dipoles (tangential to the layers) in the plane z = 0. Receivers: contact (just under the
    skin surface; the grid puts them on it, tracer_spec moves them 10 um into the skin) on the
    normal and 30 / 50 mm lateral; mid-fat; in air 10 and 30 mm off the skin on the normal,
    20 mm lateral at 10 mm (an exit about 50 deg from the normal) and 60 mm lateral at 10 mm
    (about 77 deg: a grazing exit). The FDTD box is aligned so that the interfaces lie on cell
    faces of the 2 mm grid (bounds multiples of 6 mm, so that 1.5 and 3 mm grids share the
    y = 0 face); on those the layers move to the nearest faces (1.5 mm: skin 1.5, fat 21 mm; 3 mm:
    skin 3, fat 18), and the tracer answers on that geometry (:func:`layered_on_grid`)."""
    ph = layered_phantom()
    tx = [0.0, SKIN_M + FAT_M + TX_DEPTH_M, 0.0]
    rxs = (
        _dipole("contact_0mm", [0.0, 0.0005, 0.0]),
        _dipole("contact_30mm", [0.030, 0.0005, 0.0]),
        _dipole("contact_50mm", [0.050, 0.0005, 0.0]),
        _dipole("fat_mid", [0.0, SKIN_M + FAT_M / 2, 0.0]),
        _dipole("air_10mm", [0.0, -0.010, 0.0]),
        _dipole("air_30mm", [0.0, -0.030, 0.0]),
        _dipole("air_10mm_20lat", [0.020, -0.010, 0.0]),
        _dipole("air_10mm_60lat_grazing", [0.060, -0.010, 0.0]),
    )
    spec = ChannelSpec(_dipole("tx", tx), rxs, phantom=ph.name, frequency_hz=F0_HZ,
                       max_interactions=LAYERED_INTERACTIONS, rays=100_000)
    return spec, ph, FdtdOptions(cell_m=0.002, bounds_m=_aligned_bounds(tx, rxs), pml_cells=10)


#: Lateral offsets of the contact sensors of :func:`lateral_case` [m].
LATERAL_OFFSETS_M = (0.0, 0.010, 0.020, 0.025, 0.030, 0.035, 0.040, 0.045, 0.050, 0.055)


def lateral_case() -> tuple[ChannelSpec, Phantom, FdtdOptions]:
    """The layered stack of :func:`layered_case` with only contact sensors (0.5 mm under the skin
    surface), on the normal and every 5-10 mm up to 55 mm lateral: the direct path crosses the fat
    from 0 to ~65 deg off its normal, approaching the 26.6 deg critical cone in the muscle. It
    places the angle beyond which GO loses more than the on-normal ~1 dB (docs/validation.md,
    "Validity per receiver"). Same grid alignment as the layered case."""
    ph = layered_phantom()
    tx = [0.0, SKIN_M + FAT_M + TX_DEPTH_M, 0.0]
    rxs = tuple(_dipole(f"contact_{x * 1e3:g}mm", [x, 0.0005, 0.0]) for x in LATERAL_OFFSETS_M)
    spec = ChannelSpec(_dipole("tx", tx), rxs, phantom=ph.name, frequency_hz=F0_HZ,
                       max_interactions=LAYERED_INTERACTIONS, rays=100_000)
    return spec, ph, FdtdOptions(cell_m=0.002, bounds_m=_aligned_bounds(tx, rxs), pml_cells=10)


#: The wall case's stack (the issue's full-wave check): skin 2 mm, fat 10 mm, muscle 20 mm, small
#: intestine behind it, where the capsule is, 50 mm under the skin surface.
WALL_LAYERS = (("skin", "skin_dry", 0.0), ("fat", DEFAULT_FAT, 0.002), ("muscle", "muscle", 0.012),
               ("small_intestine", "small_intestine", 0.032))
WALL_DEPTH_M = 0.050


def wall_case() -> tuple[ChannelSpec, Phantom, FdtdOptions]:
    """Capsule in the small intestine 50 mm under the skin, behind 20 mm of muscle, 10 mm of fat and
    2 mm of skin. Contact sensors (0.5 mm under the skin surface) on the normal and 10-50 mm aside
    (11-45 deg off the normal at the capsule); receivers in air 10 mm off the skin, 6, 11, 17 and 27
    mm aside: the direct path leaves the skin at about 20, 35, 50 and 65 deg (the exit angles of
    the issue's oblique lossy case)."""
    ph = stack_phantom(WALL_LAYERS, "wall")
    tx = [0.0, WALL_DEPTH_M, 0.0]
    rxs = tuple(_dipole(f"contact_{x:g}mm", [x * 1e-3, 0.0005, 0.0]) for x in (0, 10, 20, 30, 40, 50))
    rxs += tuple(_dipole(f"air_exit{a}", [x * 1e-3, -0.010, 0.0]) for a, x in ((20, 6), (35, 11), (50, 17), (65, 27)))
    spec = ChannelSpec(_dipole("tx", tx), rxs, phantom=ph.name, frequency_hz=F0_HZ,
                       max_interactions=LAYERED_INTERACTIONS, rays=100_000)
    return spec, ph, FdtdOptions(cell_m=0.002, bounds_m=_aligned_bounds(tx, rxs), pml_cells=10)


#: The deep cases' stack: skin 2 mm, fat 16 mm, muscle (the capsule's medium).
DEEP_LAYERS = (("skin", "skin_dry", 0.0), ("fat", DEFAULT_FAT, 0.002), ("muscle", "muscle", 0.018))
#: Contact sensors' angles off the normal at the capsule [deg].
DEEP_ANGLES_DEG = (0.0, 15.0, 30.0, 40.0)


def deep_case(depth_m: float) -> tuple[ChannelSpec, Phantom, FdtdOptions]:
    """A capsule ``depth_m`` under the skin in muscle behind 16 mm of fat and 2 mm of skin; contact
    sensors 0.5 mm under the skin surface at 0, 15, 30 and 40 deg off the normal seen from the
    capsule (lateral offsets ``depth tan(angle)``)."""
    ph = stack_phantom(DEEP_LAYERS, "deep")
    tx = [0.0, depth_m, 0.0]
    rxs = tuple(_dipole(f"contact_{a:g}deg", [depth_m * np.tan(np.radians(a)), 0.0005, 0.0]) for a in DEEP_ANGLES_DEG)
    spec = ChannelSpec(_dipole("tx", tx), rxs, phantom=ph.name, frequency_hz=F0_HZ,
                       max_interactions=LAYERED_INTERACTIONS, rays=100_000)
    return spec, ph, FdtdOptions(cell_m=0.002, bounds_m=_aligned_bounds(tx, rxs), pml_cells=10)


def homogeneous_case() -> tuple[ChannelSpec, Phantom, FdtdOptions]:
    """The test suite's homogeneous muscle case (tests/fullwave/test_gprmax_homogeneous.py): z dipoles
    0.5 m deep in the half-space phantom, receivers 5 and 10 cm broadside."""
    from raytrace.body.library import get_phantom

    ph = get_phantom("half-space")
    tx = np.array([0.0, 0.5, 0.0])
    spec = ChannelSpec(_dipole("tx", tx), (_dipole("r5", tx + [0.05, 0, 0]), _dipole("r10", tx + [0.10, 0, 0])),
                       phantom="half-space", frequency_hz=F0_HZ)
    return spec, ph, FdtdOptions(cell_m=0.002, margin_m=0.02, pml_cells=10)


def torso_case() -> tuple[ChannelSpec, Phantom, FdtdOptions]:
    """The default torso (resolution 48), capsule at ``small_intestine_1``; contact sensors placed
    like the belt's (1 mm inside the skin) in the capsule's transverse plane at polar 0
    (anterior), 20 and 40 deg, and one in air 10 mm in front of the anterior one. The FDTD box is
    the antennas' box grown by 20 mm: air in front, the body cut elsewhere (unbounded there)."""
    ph = default_torso()
    tx = np.asarray(ph.sites["small_intestine_1"].position_m, float)
    z = float(tx[2])
    ant = contact_point(ph, 0.0, z)
    rxs = (
        _dipole("contact_anterior", ant),
        _dipole("contact_20deg", contact_point(ph, 20.0, z)),
        _dipole("contact_40deg", contact_point(ph, 40.0, z)),
        _dipole("air_10mm_anterior", ant + [0.0, -0.011, 0.0]),
    )
    spec = ChannelSpec(_dipole("tx", tx), rxs, phantom=ph.name, frequency_hz=F0_HZ, max_interactions=6,
                       rays=100_000)
    return spec, ph, FdtdOptions(cell_m=0.002, margin_m=0.02, pml_cells=10)


#: Each case and the cell ratio of its second (discretisation) run: 1.5 mm beside 2 mm everywhere (3 mm,
#: a cell coarser than the 2 mm skin, moves contact sensors across it; ``--coarse-factor 1.5`` runs it).
#: The torso's contact sensors snap to other nodes on the 1.5 mm grid (up to a cell across the 2 mm
#: skin), so its two runs compare neighbouring receivers (docs/validation.md says by how much).
CASES = {"homogeneous": (homogeneous_case, 0.75), "layered": (layered_case, 0.75), "lateral": (lateral_case, 0.75),
         "wall": (wall_case, 0.75), "deep30": (lambda: deep_case(0.030), 0.75),
         "deep100": (lambda: deep_case(0.100), 0.75), "torso": (torso_case, 0.75)}
#: The planar cases' layers (outside in: organ, tissue, front face y), for the exact layered field.
PLANAR_LAYERS = {"layered": tuple(_layered()), "lateral": tuple(_layered()), "wall": WALL_LAYERS,
                 "deep30": DEEP_LAYERS, "deep100": DEEP_LAYERS}
#: The phantom the tracer answers on per cell size (fullwave.run.compare's ``grid_phantom``).
GRID_PHANTOMS = {"layered": layered_on_grid, "lateral": layered_on_grid,
                 "wall": lambda h: on_grid(WALL_LAYERS, "wall", h), "deep30": lambda h: on_grid(DEEP_LAYERS, "deep", h),
                 "deep100": lambda h: on_grid(DEEP_LAYERS, "deep", h)}
