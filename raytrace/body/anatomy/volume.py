"""Labelled volumes (NIfTI-1/2 through nibabel) -> one closed surface per label.

:func:`open_volume` reads only the header: the voxel count is refused above ``max_voxels`` and the
memory of the decoded labels above ``max_bytes`` before any voxel is decoded (a .nii.gz declares its
shape in its header, so a small file cannot make the build decode a huge array). Spatial units of the
header (``xyzt_units``: metres, millimetres or microns) are converted to the manifest's file units.

:func:`label_surface` meshes one label (docs/phantoms.md, "Labelled volumes"): the label's voxels,
with enclosed cavities filled (``binary_fill_holes``: an organ is a solid, whatever lies inside it is
another organ nested in it), are smoothed by a Gaussian of ``smoothing_voxels`` voxels and meshed by
marching cubes at the half level in voxel coordinates, then mapped through the volume's affine (the
triangles' winding reversed when the affine mirrors); the build decimates it to the organ's budget.
The half level of a smoothed step lies on the voxels' boundary, so the surface encloses the voxels'
volume up to the rounding of corners (curvature shrinks it by about ``sigma^2 * mean curvature``).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import trimesh

from raytrace.body.anatomy.manifest import Options
from raytrace.errors import Field, PhantomValidationError

__all__ = ["LabelVolume", "label_surface", "open_volume"]

_UNIT_MM = {"mm": 1.0, "meter": 1000.0, "micron": 1e-3, "unknown": 1.0}


def _fail(reason: str, where: Field) -> PhantomValidationError:
    return PhantomValidationError(reason, field=where)


@dataclass
class LabelVolume:
    name: str
    shape: tuple[int, int, int]
    affine: np.ndarray  # voxel index -> file units
    image: object
    _labels: np.ndarray | None = None

    def labels(self, where: Field) -> np.ndarray:
        if self._labels is None:
            try:
                data = np.asanyarray(self.image.dataobj)  # type: ignore[attr-defined]
            except Exception as exc:  # a truncated or corrupt voxel block
                raise _fail(f"{self.name}: its voxels cannot be read: {str(exc)[:200]}", where) from None
            data = data.reshape(self.shape)
            if np.issubdtype(data.dtype, np.floating):
                if not np.all(np.isfinite(data)) or np.any(data != np.round(data)):
                    raise _fail(f"{self.name} holds non-integer values: a labelled volume holds label numbers", where)
            self._labels = data.astype(np.int32, copy=False)
        return self._labels


def open_volume(path: Path, where: Field, *, scale_m_per_unit: float, max_bytes: int,
                max_voxels: int) -> LabelVolume:
    """The volume's header, checked against the caps (module docstring)."""
    import nibabel

    path = Path(path)
    try:
        size = path.stat().st_size
    except OSError as exc:
        raise _fail(f"{path.name}: cannot be read ({exc.strerror or exc})", where) from None
    if size > max_bytes:
        raise _fail(f"{path.name} is {size} bytes, over the cap of {max_bytes} bytes per file", where)
    try:
        image = nibabel.load(str(path))
    except Exception as exc:
        raise _fail(f"{path.name} is not a readable NIfTI volume: {str(exc)[:200]}", where) from None
    shape = tuple(int(n) for n in image.shape)
    if len(shape) == 4 and shape[3] == 1:
        shape = shape[:3]
    if len(shape) != 3 or min(shape) < 1:
        raise _fail(f"{path.name} has shape {shape}: a labelled volume is 3-D", where)
    voxels = int(np.prod(shape, dtype=np.int64))
    if voxels > max_voxels:
        raise _fail(f"{path.name} declares {'x'.join(map(str, shape))} = {voxels:.3g} voxels, over the cap of "
                    f"{max_voxels:.3g}: crop or resample the volume", where)
    bytes_needed = voxels * (image.get_data_dtype().itemsize + 4)
    if bytes_needed > max_bytes * 64:
        raise _fail(f"{path.name} would take {bytes_needed / 2**20:.0f} MiB decoded, over the build's memory bound",
                    where)
    affine = np.asarray(image.affine, float)
    if not np.isfinite(affine).all() or abs(np.linalg.det(affine[:3, :3])) < 1e-12:
        raise _fail(f"{path.name} has a singular or non-finite affine", where)
    unit = image.header.get_xyzt_units()[0] or "unknown"
    mm = _UNIT_MM.get(unit, 1.0)
    affine = affine.copy()
    affine[:3, :] *= mm * 1e-3 / scale_m_per_unit  # world (mm) -> the manifest's file units
    return LabelVolume(path.name, shape, affine, image)  # type: ignore[arg-type]


def label_surface(volume: LabelVolume, label: int, where: Field, organ: str,
                  options: Options) -> tuple[trimesh.Trimesh, list[str]]:
    """The closed surface of one label, in file units (module docstring)."""
    from scipy.ndimage import binary_fill_holes, gaussian_filter
    from skimage.measure import marching_cubes

    labels = volume.labels(where)
    mask = labels == label
    count = int(mask.sum())
    if count == 0:
        present = np.unique(labels)
        present = present[present != 0]
        shown = ", ".join(str(int(v)) for v in present[:20]) + (" ..." if len(present) > 20 else "")
        raise _fail(f"label {label} of organ {organ!r} is missing from {volume.name} (labels present: "
                    f"{shown or 'none'})", where)
    sigma = options.smoothing_voxels
    pad = int(np.ceil(3 * sigma)) + 2
    idx = np.argwhere(mask)
    lo = np.maximum(idx.min(axis=0) - pad, 0)
    hi = np.minimum(idx.max(axis=0) + pad + 1, volume.shape)
    crop = np.zeros(tuple(hi - lo + 2 * pad), dtype=bool)  # padded with zeros beyond the volume's edge too
    crop[pad:pad + (hi - lo)[0], pad:pad + (hi - lo)[1], pad:pad + (hi - lo)[2]] = mask[lo[0]:hi[0], lo[1]:hi[1],
                                                                                      lo[2]:hi[2]]
    filled = binary_fill_holes(crop)
    notes = []
    if filled.sum() > crop.sum():
        notes.append(f"filled {int(filled.sum() - crop.sum())} voxels of cavities inside label {label}")
    field = gaussian_filter(filled.astype(np.float32), sigma=sigma) if sigma > 0 else filled.astype(np.float32)
    verts, faces, _, _ = marching_cubes(field, level=0.5, allow_degenerate=False)
    verts = verts + (lo - pad)  # voxel indices of the whole volume
    world = verts @ volume.affine[:3, :3].T + volume.affine[:3, 3]
    mesh = trimesh.Trimesh(world, faces, process=True, validate=True)
    if mesh.volume < 0:
        mesh.invert()
    voxel_volume = abs(np.linalg.det(volume.affine[:3, :3])) * count
    notes.append(f"meshed label {label} ({count} voxels, {voxel_volume:.4g} cubic file units) by marching cubes "
                 f"after a {sigma:g}-voxel Gaussian ({len(mesh.faces)} triangles)")
    return mesh, notes
