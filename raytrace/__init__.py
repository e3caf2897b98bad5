"""CapsuleRT's ray tracer: in-body radio channels through lossy, dispersive tissue.

The front door::

    import raytrace as rt

    spec = rt.ChannelSpec(transmitter=rt.Antenna(site="small_intestine_1"),
                          receivers=[rt.Antenna(site="belt_anterior")], frequency_hz=402e6)
    result = rt.trace_channel(spec)          # the built-in phantom spec.phantom names ("torso")
    for path in result.profiles[0].paths:
        print(path.delay_s, path.gain_db)

The package is layered; each layer imports only the ones above it in this list
(``docs/architecture.md``):

* :mod:`raytrace.physics` — constants, tissue dielectric models, materials, the
  electromagnetics of interfaces (no geometry);
* :mod:`raytrace.body` — phantoms (closed nested organ meshes), shapes, the default
  torso, glTF import/export, the built-in library;
* :mod:`raytrace.engine` — Embree and the compiled (numba) kernels: the only place
  that imports numba, llvmlite or ctypes;
* :mod:`raytrace.solver` — launching, shooting and bouncing, the direct-path search,
  Newton refinement, the fields along a path, the tracer that runs them in order;

and beside them the request and the answer: :mod:`raytrace.spec`
(:class:`ChannelSpec`, :class:`Antenna`), :mod:`raytrace.results`
(:class:`ChannelResult`), :mod:`raytrace.scenarios` (ready-made specs) and
:mod:`raytrace.solver.config` (:class:`TracerConfig`, how the search is tuned).
"""

from raytrace.body.library import builtin_phantoms, get_phantom
from raytrace.body.phantom import Organ, Phantom, Site
from raytrace.body.torso import default_torso
from raytrace.errors import (
    AmbiguousPositionError,
    BudgetExceededError,
    CapsuleRTError,
    FrequencyOutOfRangeError,
    InputError,
    InvalidGeometryError,
    NotFoundError,
    PhantomValidationError,
    UnknownTissueError,
)
from raytrace.physics.materials import Material
from raytrace.results import ChannelResult, Interaction, Path, ReceiverProfile, Segment, TraceStats
from raytrace.scenarios import SCENARIOS, Scenario, get_scenario
from raytrace.solver.budget import Budget
from raytrace.solver.config import TracerConfig
from raytrace.solver.tracer import trace_channel, warm_up
from raytrace.spec import Antenna, Band, ChannelSpec

__all__ = [
    "AmbiguousPositionError",
    "Antenna",
    "Band",
    "Budget",
    "BudgetExceededError",
    "CapsuleRTError",
    "ChannelResult",
    "ChannelSpec",
    "FrequencyOutOfRangeError",
    "InputError",
    "Interaction",
    "InvalidGeometryError",
    "Material",
    "NotFoundError",
    "Organ",
    "Path",
    "Phantom",
    "PhantomValidationError",
    "ReceiverProfile",
    "SCENARIOS",
    "Scenario",
    "Segment",
    "Site",
    "TraceStats",
    "TracerConfig",
    "UnknownTissueError",
    "builtin_phantoms",
    "default_torso",
    "get_phantom",
    "get_scenario",
    "trace_channel",
    "warm_up",
]
