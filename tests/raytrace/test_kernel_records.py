"""The kernels' records (raytrace/engine/records.py): a record whose fields are swapped, of the
wrong dtype, shape, layout or range, or read-only where the kernel writes, is refused in Python
with an error naming the record and the field, before compiled code (which checks no bounds)
could read it as something else. The tables the solver builds pass."""

from __future__ import annotations

import numpy as np
import pytest

from raytrace.body.library import half_space
from raytrace.engine import records
from raytrace.engine.records import MediaTables, RecordError, SceneTables, TraceState, build
from raytrace.engine.scene import scene_for
from raytrace.solver.media import MediaTable


@pytest.fixture(scope="module")
def tables():
    phantom = half_space()
    media = MediaTable.build(phantom, np.array([402e6]))
    scene = scene_for(phantom, ~media.face_transparent)
    return scene.kernel_tables, media.kernel_tables


def _fields(record) -> dict:
    return dict(zip(record._fields, record))


def test_the_solvers_tables_are_valid_records(tables):
    scene, media = tables
    assert isinstance(scene, SceneTables) and isinstance(media, MediaTables)
    assert build(SceneTables, **_fields(scene)) == scene
    assert len(media.material_class) == len(media.parent) + 1  # M organs, M + 1 media with air


def test_a_swapped_pair_of_same_dtype_tables_is_refused(tables):
    """parent (M,) and material_class (M + 1,) are both int64: swapped, the named dimensions
    disagree."""
    _scene, media = tables
    fields = _fields(media) | {"parent": media.material_class, "material_class": media.parent}
    with pytest.raises(RecordError, match=r"MediaTables\.material_class: expected int64 \(M\+1=.*got shape"):
        build(MediaTables, **fields)


def test_a_swapped_pair_of_same_shape_tables_is_refused(tables):
    """plane_d (F,) float64 and face_organ (F,) int64 swapped: the dtypes disagree."""
    scene, _media = tables
    fields = _fields(scene) | {"plane_d": scene.face_organ, "face_organ": scene.plane_d}
    with pytest.raises(RecordError, match=r"SceneTables\.plane_d: expected dtype float64, got int64"):
        build(SceneTables, **fields)


@pytest.mark.parametrize("change, message", [
    (lambda s: {"face_normals": s.face_normals.astype(np.float32)}, r"normals: expected dtype float64, got float32"),
    (lambda s: {"frame": np.asfortranarray(s.frame)}, r"frame: must be C-contiguous"),
    (lambda s: {"face_map": s.face_map + len(s.face_normals)}, r"face_map: values must lie in \[0=0, F="),
    (lambda s: {"frame": s.frame[:, :21].copy()}, r"frame: expected float64 \(F=\d+, 22\), got shape"),
    (lambda s: {"base": s.base + len(s.face_normals)}, r"base: values must lie in \[0=0, F="),
    (lambda s: {"center": list(s.center)}, r"center: expected a numpy array"),
    (lambda s: {"handle": 0}, r"handle: must not be 0"),
    (lambda s: {"offset_m": np.nan}, r"offset_m: expected a finite number"),
])
def test_a_wrong_field_is_refused_with_its_name(tables, change, message):
    scene, _media = tables
    with pytest.raises(RecordError, match=message):
        build(SceneTables, **(_fields(scene) | change(scene)))


def test_an_output_must_be_writeable_and_record_mode_needs_one_target_per_ray():
    p = 3
    state = dict(o=np.zeros((p, 3)), d=np.zeros((p, 3)), med=np.zeros(p, np.int64), push=np.zeros((p, 3)),
                 k=np.zeros(p, np.int64), nint=np.ones(p, np.int64), ok=np.ones(p, bool), done=np.zeros(p, bool),
                 codes=np.zeros((p, 1), np.int64), targets=np.zeros((0, 3)), record=False)
    assert isinstance(build(TraceState, **state), TraceState)
    frozen = np.zeros((p, 3))
    frozen.flags.writeable = False
    with pytest.raises(RecordError, match=r"TraceState\.o: the kernel writes into it"):
        build(TraceState, **(state | {"o": frozen}))
    with pytest.raises(RecordError, match=r"TraceState\.targets: 0 rows; record mode needs one per ray"):
        build(TraceState, **(state | {"record": True}))
    with pytest.raises(RecordError, match=r"TraceState\.ok: expected bool \(P=3,\), got shape \(2,\)"):
        build(TraceState, **(state | {"ok": np.ones(2, bool)}))
    with pytest.raises(RecordError, match=r"missing fields \['record'\]"):
        build(TraceState, **{k: v for k, v in state.items() if k != "record"})


def test_every_record_declares_every_field():
    """Each field of each record says what the kernels are compiled for (an Array or a Scalar)."""
    classes = [c for c in vars(records).values() if isinstance(c, type) and issubclass(c, tuple)
               and hasattr(c, "_fields") and c.__module__ == records.__name__]
    assert len(classes) >= 15
    for cls in classes:
        assert len(records._fields(cls)) == len(cls._fields)
