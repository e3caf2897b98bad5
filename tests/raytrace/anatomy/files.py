"""Anatomy files the tests write themselves, in every input format, and their closed forms."""

from __future__ import annotations

import json
from pathlib import Path

import meshio
import numpy as np
import trimesh
import yaml


def sphere(radius: float, center=(0.0, 0.0, 0.0), subdivisions: int = 3) -> trimesh.Trimesh:
    mesh = trimesh.creation.icosphere(subdivisions=subdivisions, radius=radius)
    mesh.apply_translation(center)
    return mesh


def polyhedron_volume(vertices: np.ndarray, faces: np.ndarray) -> float:
    """Signed volume by the divergence theorem (sum of tetrahedra to the origin): an oracle that shares
    no code with trimesh or the pipeline."""
    a, b, c = (np.asarray(vertices, float)[np.asarray(faces)[:, k]] for k in range(3))
    return float(np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6.0)


def write_polydata(path: Path, mesh: trimesh.Trimesh) -> None:
    """Legacy ASCII VTK POLYDATA, as segmentation tools export it (the test's own writer)."""
    lines = ["# vtk DataFile Version 3.0", "test surface", "ASCII", "DATASET POLYDATA",
             f"POINTS {len(mesh.vertices)} float"]
    lines += [" ".join(f"{x:.9g}" for x in v) for v in mesh.vertices]
    lines.append(f"POLYGONS {len(mesh.faces)} {4 * len(mesh.faces)}")
    lines += [f"3 {a} {b} {c}" for a, b, c in mesh.faces]
    path.write_text("\n".join(lines) + "\n")


def write_surface(path: Path, mesh: trimesh.Trimesh) -> None:
    """``mesh`` in the format of ``path``'s suffix; ``.vtk`` is POLYDATA, ``_ug.vtk`` an unstructured grid."""
    path = Path(path)
    name = path.name
    if name.endswith("_ug.vtk"):
        meshio.Mesh(mesh.vertices, [("triangle", mesh.faces)]).write(path, file_format="vtk", binary=False)
    elif name.endswith(".vtk"):
        write_polydata(path, mesh)
    elif name.endswith(".glb"):
        scene = trimesh.Scene()
        scene.add_geometry(mesh, node_name="surface", geom_name="surface")
        path.write_bytes(scene.export(file_type="glb"))
    else:
        fmt = {".vtu": "vtu", ".stl": "stl", ".ply": "ply", ".obj": "obj", ".off": "off"}[path.suffix]
        meshio.Mesh(mesh.vertices, [("triangle", mesh.faces)]).write(path, file_format=fmt)


def write_manifest(directory: Path, manifest: dict, name: str = "manifest.yaml") -> Path:
    path = Path(directory) / name
    path.write_text(json.dumps(manifest) if name.endswith(".json") else yaml.safe_dump(manifest))
    return path
