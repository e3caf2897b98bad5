"""The fields of many sensors (estimators.localization.fieldstore): the disk cache gives back the
solved fields bit for bit without rebuilding the grid (a restarted server), writes atomically, stays
within its bound, treats a damaged file as a miss; the parallel solves equal the serial ones bit
for bit; errors name the sensor, budgets stop the work.

Oracle: the fields solved directly by ``travel_time_field`` on the same arrays in this process
(equality, not a tolerance: the same code on the same numbers)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from estimators.errors import EstimatorInputError
from estimators.localization import fieldstore, travel_time_field
from estimators.localization.traveltime import cache_info, clear_cache

H = 0.004
SHAPE = (24, 20, 22)
#: two layers (index 5 below z = 40 mm, 8 above) and an air pocket (NaN) in one corner
INDEX = np.where(np.arange(SHAPE[2])[None, None, :] < 10, 5.0, 8.0) * np.ones(SHAPE)
INDEX[:4, :4, :4] = np.nan
ORIGIN = np.array([0.01, -0.02, 0.0])
SENSORS = ORIGIN + np.array([[0.03, 0.03, 0.02], [0.07, 0.05, 0.06], [0.05, 0.02, 0.08], [0.08, 0.07, 0.03]])


def grid_builder(calls: list):
    def build():
        calls.append(1)
        return INDEX, ORIGIN, H
    return build


def same(a, b) -> bool:
    return all(np.array_equal(getattr(a, f.name), getattr(b, f.name)) for f in dataclasses.fields(a))


@pytest.fixture(autouse=True)
def empty_memory():
    clear_cache()
    yield
    clear_cache()


def test_disk_cache_gives_the_fields_back_without_building_the_grid(tmp_path):
    calls: list = []
    first = fieldstore.fields_for_sensors("grid-a", SENSORS, grid_builder(calls), cache_dir=tmp_path, workers=1)
    assert len(calls) == 1 and len(list(tmp_path.glob("*.npz"))) == 4
    for f, s in zip(first.fields, SENSORS):
        assert same(f, travel_time_field(INDEX, ORIGIN, H, s))
    clear_cache()  # a restarted process: nothing in memory
    again = fieldstore.fields_for_sensors("grid-a", SENSORS[::-1], grid_builder(calls), cache_dir=tmp_path)
    assert len(calls) == 1  # every field from disk: the grid was not built again
    assert all(same(a, b) for a, b in zip(again.fields, first.fields[::-1]))
    assert cache_info()["fields"] == 4  # and now in memory too
    # another grid key is another grid
    fieldstore.fields_for_sensors("grid-b", SENSORS[:1], grid_builder(calls), cache_dir=tmp_path, workers=1)
    assert len(calls) == 2 and len(list(tmp_path.glob("*.npz"))) == 5


def test_parallel_solves_equal_the_serial_ones(tmp_path):
    serial = fieldstore.fields_for_sensors("grid-p", SENSORS, grid_builder([]), workers=1)
    clear_cache()
    parallel = fieldstore.fields_for_sensors("grid-p", SENSORS, grid_builder([]), workers=2)
    assert all(same(a, b) for a, b in zip(serial.fields, parallel.fields))


def test_a_damaged_file_is_a_miss_and_is_rewritten(tmp_path):
    calls: list = []
    first = fieldstore.fields_for_sensors("grid-d", SENSORS[:2], grid_builder(calls), cache_dir=tmp_path, workers=1)
    victim = tmp_path / (fieldstore.field_key("grid-d", SENSORS[0], 2, 1.5) + ".npz")
    assert victim.exists()
    victim.write_bytes(victim.read_bytes()[:1000])  # truncated, as by a crash of a non-atomic writer
    clear_cache()
    again = fieldstore.fields_for_sensors("grid-d", SENSORS[:2], grid_builder(calls), cache_dir=tmp_path, workers=1)
    assert len(calls) == 2 and same(again.fields[0], first.fields[0]) and same(again.fields[1], first.fields[1])
    clear_cache()
    fieldstore.fields_for_sensors("grid-d", SENSORS[:2], grid_builder(calls), cache_dir=tmp_path)
    assert len(calls) == 2  # rewritten whole: a hit now


def test_a_failed_write_leaves_no_file_and_loses_only_the_cache_entry(tmp_path, monkeypatch):
    def broken_savez(fh, **arrays):
        fh.write(b"PK\x03\x04 half a file")
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(fieldstore.np, "savez", broken_savez)
    fields = fieldstore.fields_for_sensors("grid-w", SENSORS[:2], grid_builder([]), cache_dir=tmp_path, workers=1)
    assert len(fields) == 2 and np.isfinite(fields.time_s).all()
    assert list(tmp_path.iterdir()) == []  # neither a final file nor a temporary one


def test_the_disk_cache_stays_within_its_bound_dropping_the_least_recently_used(tmp_path):
    one = fieldstore.fields_for_sensors("grid-e", SENSORS[:1], grid_builder([]), cache_dir=tmp_path, workers=1)
    size = fieldstore.disk_cache_bytes(tmp_path)
    assert size > one.time_s.nbytes  # the times, the domain and a few scalars
    bound = int(2.5 * size)  # room for two fields
    fieldstore.fields_for_sensors("grid-e", SENSORS, grid_builder([]), cache_dir=tmp_path, max_bytes=bound, workers=1)
    assert fieldstore.disk_cache_bytes(tmp_path) <= bound
    kept = {p.name for p in tmp_path.glob("*.npz")}
    assert kept == {fieldstore.field_key("grid-e", s, 2, 1.5) + ".npz" for s in SENSORS[2:]}


def test_errors_name_the_sensor_and_come_before_any_solve(tmp_path):
    outside = SENSORS.copy()
    outside[2] = [0.5, 0.0, 0.0]  # beyond the grid
    with pytest.raises(EstimatorInputError) as info:
        fieldstore.fields_for_sensors("grid-x", outside, grid_builder([]), cache_dir=tmp_path, workers=1)
    assert info.value.field == "sensors[2].position_m"
    assert cache_info()["fields"] == 0 and not list(tmp_path.iterdir())
    in_air = SENSORS.copy()
    in_air[3] = ORIGIN + 0.5 * H * np.array([1.0, 1.0, 1.0])  # in the NaN pocket: outside the domain
    with pytest.raises(EstimatorInputError) as info:
        fieldstore.fields_for_sensors("grid-x", in_air, grid_builder([]), workers=2, field="receivers")
    assert info.value.field == "receivers[3].position_m" and "outside the propagation domain" in info.value.reason


@pytest.mark.parametrize("workers", [1, 2])
def test_a_budget_stops_between_solves(workers):
    class Stop(Exception):
        pass

    calls = []

    def check():
        calls.append(1)
        if len(calls) > 2:
            raise Stop

    with pytest.raises(Stop):
        fieldstore.fields_for_sensors("grid-s", SENSORS, grid_builder([]), workers=workers, check=check)
    assert cache_info()["fields"] < len(SENSORS)


def test_a_plain_script_without_a_main_guard_is_not_run_again_by_the_workers(tmp_path):
    """Spawned workers import the parent's __main__ again: a script without ``if __name__ ==
    "__main__"`` would run once per worker (and start pools of its own). Such a script gets the serial
    path: its body runs once and the fields are the same."""
    import os
    import subprocess
    import sys
    from pathlib import Path

    script = tmp_path / "fix.py"
    script.write_text(
        "import numpy as np\n"
        "from estimators.localization import fieldstore\n"
        "print('body', flush=True)\n"
        "index = np.full((12, 12, 12), 5.0)\n"
        "s = np.array([[0.01, 0.01, 0.01], [0.03, 0.02, 0.02], [0.02, 0.035, 0.03]])\n"
        "f = fieldstore.fields_for_sensors('g', s, lambda: (index, np.zeros(3), 0.004))\n"
        "print('fields', len(f), flush=True)\n")
    root = Path(fieldstore.__file__).resolve().parents[2]
    out = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, timeout=300,
                         env={**os.environ, "PYTHONPATH": str(root)})
    assert out.returncode == 0, out.stderr
    assert out.stdout.split() == ["body", "fields", "3"], out.stdout
