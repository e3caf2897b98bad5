"""Per-medium optical constants for one trace: complex refractive indices at
every requested frequency, and which triangles are transparent.

Medium index ``m`` (``-1`` air, ``i >= 0`` organ i) is stored at column
``m + 1``. With a ``homogeneous`` override every organ's material is replaced
by that one material (air stays air), the thesis' homogeneous case; a surface
whose two sides hold the same material is *transparent*: the tracer neither
reflects nor bends there (it only splits the path's segments).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from raytrace.body.phantom import AIR, Material, Phantom
from raytrace.engine.records import MediaTables, build
from raytrace.physics.em import refractive_index


@dataclass(frozen=True)
class MediaTable:
    """``n[f, m + 1]``: complex refractive index (Re > 0, Im <= 0) of medium m at frequency f."""

    frequencies_hz: np.ndarray  # (F,) first one is the centre (geometry) frequency
    n: np.ndarray  # (F, M + 1) complex
    n_group: np.ndarray  # (F, M + 1) real group index Re(n + w dn/dw)
    materials: tuple[Material, ...]  # (M + 1,) air first
    face_transparent: np.ndarray  # (F_tri,) bool
    parent: np.ndarray  # (M,) organ -> parent medium index
    material_class: np.ndarray  # (M + 1,) same id <=> same material (medium m at m + 1)

    @property
    def n_real(self) -> np.ndarray:
        """Re n at the centre frequency, used for all ray geometry (Snell directions, delays)."""
        return self.n[0].real

    @cached_property
    def kernel_tables(self) -> MediaTables:
        """The parent, material class, face transparency and Re n tables the exact kernels of
        :mod:`raytrace.engine.kernels` take."""
        return build(MediaTables, parent=np.ascontiguousarray(self.parent, np.int64),
                     material_class=np.ascontiguousarray(self.material_class, np.int64),
                     transparent=np.ascontiguousarray(self.face_transparent, np.bool_),
                     n_real=np.ascontiguousarray(self.n_real, np.float64))

    @classmethod
    def build(
        cls,
        phantom: Phantom,
        frequencies_hz: np.ndarray,
        homogeneous: Material | None = None,
    ) -> "MediaTable":
        """The table at ``frequencies_hz`` (checked by :class:`raytrace.spec.ChannelSpec`; the
        tissue model refuses frequencies outside its range)."""
        f = np.asarray(frequencies_hz, dtype=float).ravel()
        organ_materials = [homogeneous if homogeneous is not None else o.material for o in phantom.organs]
        materials = (AIR, *organ_materials)
        n = np.stack(
            [refractive_index(np.broadcast_to(m.complex_relative_permittivity(f), f.shape)) for m in materials],
            axis=1,
        ).astype(complex)
        n_group = np.stack([np.broadcast_to(m.group_index(f), f.shape) for m in materials], axis=1).astype(float)
        parent = np.asarray(phantom.parent, dtype=np.int64)
        organ = np.asarray(phantom.face_organ, dtype=np.int64)
        same = np.array(
            [materials[i + 1] == materials[int(parent[i]) + 1] for i in range(len(phantom.organs))],
            dtype=bool,
        )
        classes = np.array([materials.index(m) for m in materials], dtype=np.int64)
        return cls(
            frequencies_hz=f,
            n=n,
            n_group=n_group,
            materials=materials,
            face_transparent=same[organ] if len(organ) else np.zeros(0, bool),
            parent=parent,
            material_class=classes,
        )
