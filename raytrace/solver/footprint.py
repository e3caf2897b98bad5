"""What a trace will cost, estimated from its request before any work.

docs/service.md, "Memory and work model of a channel request", derives and calibrates the model.

The service refuses a channel request whose estimate does not fit its limits with a 422
naming the field that makes it big, instead of starting a trace that would run out of its
budget after seconds of work. The model (derived and calibrated in docs/service.md,
"Memory and work model") is an upper envelope of measured traces on the built-in phantoms:

* depth ``d = min(k, 1 + DR / DB_PER_LEVEL)``: a ray tree grows one level per interaction
  until the weaker branch falls below the dynamic range ``DR``;
* shooting segments per launch ``s = BRANCHING ** d``;
* reception candidates per launch and receiver ``c = max(CANDIDATE_FRACTION * s, CANDIDATE_FLOOR)``;
* paths ``P = PATH_FRACTION * rays * receivers * c``;
* peak bytes = the launch batches in flight (event log + live rays + walk records)
  + the candidates + the paths (objects and JSON, with their band gains).

Geometries that focus rays (a transmitter at the centre of a sphere) can exceed the
envelope; the :class:`~raytrace.solver.budget.Budget` counts the arrays as they are
allocated and stops such a trace cleanly.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from raytrace.solver.config import TracerConfig
from raytrace.spec import ChannelSpec

#: Growth of the shooting's segments per launch with each interaction level (envelope of
#: 1.46-1.73 measured on the default torso at 300 dB, 1.0-1.35 on the test scenes).
BRANCHING = 1.75
#: Dynamic range one more level of the ray tree costs [dB] (the default torso: 40 dB prunes the
#: tree at 4 levels, 80 dB at 7).
DB_PER_LEVEL = 13.0
#: Reception candidates per launch and receiver, as a fraction of the segments per launch, and
#: their floor (torso: 0.0026 s at 10 interactions, 300 dB; 0.01 covers it 4 times).
CANDIDATE_FRACTION = 0.01
CANDIDATE_FLOOR = 0.5
#: Exact paths per estimated candidate (torso, 1e5 rays, 10 interactions, 300 dB: 46 720 paths, 0.015
#: of the estimated 3.2e6 candidates; 0.064 of the 0.73e6 there were).
PATH_FRACTION = 0.03
#: Bytes of one event-log entry (parent, code, face: 3 x int64) and of one live ray (ShotRays).
LOG_ENTRY_BYTES = 24
LIVE_RAY_BYTES = 73
#: Bytes of one walk record (per launch and receiver: miss float64, events and entry int32).
WALK_RECORD_BYTES = 16
#: Bytes of one candidate with signature width K: the batch's part (5 + 2K numbers), the merged
#: arrays (6 + 2K) and the seed selection's sort keys (K + 5).
CANDIDATE_BASE_BYTES, CANDIDATE_PER_EVENT_BYTES = 8 * 16, 8 * 5
#: Bytes of one path in the answer per event (Python objects, the response dict, its JSON:
#: 12 KB per path at 10 interactions measured) and per band point (a complex gain as numpy, as
#: a dict and as JSON).
PATH_PER_EVENT_BYTES = 1_000
PATH_PER_BAND_POINT_BYTES = 700


@dataclass(frozen=True)
class Footprint:
    """The estimate of one trace: ray segments of its shooting, and its peak bytes by term."""

    ray_segments: int
    batch_bytes: int
    candidate_bytes: int
    path_bytes: int
    band_bytes: int

    @property
    def peak_bytes(self) -> int:
        return self.batch_bytes + self.candidate_bytes + self.path_bytes + self.band_bytes

    def largest_field(self) -> str:
        """The request field whose term dominates the bytes (what to lower first): ``band.points``
        (the paths' band gains), ``max_interactions`` (the launch batches' trees), ``rays`` (the
        candidates), ``receivers`` (the paths)."""
        terms = {"band.points": self.band_bytes, "max_interactions": self.batch_bytes,
                 "rays": self.candidate_bytes, "receivers": self.path_bytes}
        return max(terms, key=terms.get)


def estimate(spec: ChannelSpec, config: TracerConfig | None = None) -> Footprint:
    """The :class:`Footprint` of tracing ``spec`` with ``config`` (module docstring; no phantom needed,
    no work done)."""
    config = config or TracerConfig()
    k, rays, n_rx = spec.max_interactions, spec.rays, len(spec.receivers)
    band_points = 0 if spec.band is None else len(spec.band.frequencies_hz)
    depth = min(float(k), 1.0 + spec.dynamic_range_db / DB_PER_LEVEL)
    per_launch = BRANCHING ** depth
    in_flight = min(config.threads, math.ceil(rays / config.launch_batch))
    batch = min(config.launch_batch, rays)
    tree = (batch * per_launch * LOG_ENTRY_BYTES + min(batch * per_launch, config.max_live_rays) * LIVE_RAY_BYTES
            + batch * n_rx * WALK_RECORD_BYTES)
    candidates = rays * n_rx * max(CANDIDATE_FRACTION * per_launch, CANDIDATE_FLOOR)
    paths = PATH_FRACTION * candidates
    return Footprint(
        ray_segments=int(math.ceil(rays * per_launch)),
        batch_bytes=int(in_flight * tree),
        candidate_bytes=int(candidates * (CANDIDATE_BASE_BYTES + CANDIDATE_PER_EVENT_BYTES * max(k, 1))),
        path_bytes=int(paths * PATH_PER_EVENT_BYTES * (k + 2)),
        band_bytes=int(paths * PATH_PER_BAND_POINT_BYTES * band_points),
    )
