"""resolve_overlaps on pairs whose surfaces touch without sharing volume (docs/phantoms.md, "Overlaps")."""

from __future__ import annotations

import numpy as np
import trimesh

from raytrace.body.anatomy.overlap import intersect, resolve_overlaps

CLEARANCE_M = 3e-4


def _touching_boxes() -> dict[str, trimesh.Trimesh]:
    """A 2 cm cube and a 1 cm cube on its +x face: the faces meet exactly in the plane x = 1 cm."""
    first = trimesh.creation.box(extents=(0.02, 0.02, 0.02))
    second = trimesh.creation.box(extents=(0.01, 0.01, 0.01))
    second.apply_translation((0.015, 0.0, 0.0))
    return {"first": first, "second": second}


def test_crossing_flagged_pair_sharing_no_volume_gives_way_by_the_clearance():
    """The pair the crossing test flags at the cut between the oesophagus and the stomach: their caps touch,
    the exact intersection holds no volume. It must give way like a touching pair (it was left as it was, and
    the phantom refused the crossing after the float32 glTF round trip)."""
    organs = _touching_boxes()
    a, b = organs["first"], organs["second"]
    shared = intersect(a, b)
    with np.errstate(divide="raise", invalid="raise"):  # as after gprMax's import in the same worker
        meshes, notes = resolve_overlaps(organs, {"first": "first", "second": "second"}, tolerance_m=1e-3,
                                         clearance_m=CLEARANCE_M, crossing={(0, 1)})
    with np.errstate(divide="ignore", invalid="ignore"):  # trimesh divides by a flat mesh's zero volume
        assert not len(shared.faces) or abs(float(shared.volume)) < 1e-15  # the premise: no shared volume

    assert meshes["first"] is a  # the organ listed first is kept
    assert notes["first"] == []
    assert len(notes["second"]) == 1 and notes["second"][0].startswith("touched 'first': gave way by 0.3 mm")
    moved = meshes["second"]
    assert moved.is_watertight
    # the later cube now starts beyond the first one's face: every vertex of the grown cube moved by exactly
    # the clearance along its unit normal, so its face moved out by more than 0 and at most the clearance
    # (1e-9 m: float64 booleans about a centimetre-sized origin)
    gap_m = float(moved.vertices[:, 0].min()) - 0.01
    assert 0.0 < gap_m <= CLEARANCE_M + 1e-9
    # what it lost is a slab of the 1 cm x 1 cm face at most the clearance thick
    removed_m3 = b.volume - moved.volume
    assert 0.0 < removed_m3 <= 1e-4 * CLEARANCE_M * (1 + 1e-6)
    np.testing.assert_allclose(moved.vertices[:, 0].max(), 0.02, atol=1e-12)  # the far face is untouched

