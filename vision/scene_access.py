"""The one place where vision/ imports the tracer (raytrace/ is being reorganised: on merge only
these imports move).

What the renderer uses: the phantom model (organs, their meshes and which organ a point is in),
the tracer's cached Embree scene of a phantom (batched first hits in float64), and the default
torso with its GI organs (``stomach``, ``small_intestine``, ``ascending_colon``,
``transverse_colon``, ``descending_colon``).
"""

from __future__ import annotations

from raytrace.errors import InputError
from raytrace.phantom import Material, Organ, Phantom
from raytrace.scene import TracerScene, scene_for
from raytrace.torso import default_torso

#: The GI organs of the default torso, whose lumen a capsule camera can be in.
GI_ORGANS = ("stomach", "small_intestine", "ascending_colon", "transverse_colon", "descending_colon")

__all__ = ["GI_ORGANS", "InputError", "Material", "Organ", "Phantom", "TracerScene", "default_torso", "scene_for"]
