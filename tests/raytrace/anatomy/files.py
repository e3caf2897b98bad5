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


def _vtk_block(array: np.ndarray, compress: bool, header: str = "<u4") -> tuple[bytes, bytes]:
    """One data array as VTK XML writes it in binary: a header of ``header`` integers (the byte count;
    compressed: one block, its raw and compressed sizes) and the bytes (zlib-compressed when ``compress``)."""
    import zlib

    raw = np.ascontiguousarray(array).tobytes()
    if not compress:
        return np.array([len(raw)], header).tobytes(), raw
    packed = zlib.compress(raw)
    return np.array([1, len(raw), len(raw), len(packed)], header).tobytes(), packed


def write_vtp(path: Path, mesh: trimesh.Trimesh, mode: str = "ascii") -> None:
    """XML VTK PolyData (.vtp) laid out as VTK's vtkXMLPolyDataWriter writes it (the test's own writer: no
    library the project may use writes .vtp): ``mode`` ascii, binary (base64 inline), appended (raw binary
    after the XML), zlib (compressed, inline) or vtk9 (VTK 9's defaults: version 2.2, UInt64 headers, raw
    appended zlib blocks, a FieldData array)."""
    import base64

    arrays = [("Points", "Float32", np.asarray(mesh.vertices, "<f4"), 3),
              ("connectivity", "Int64", np.asarray(mesh.faces, "<i8").ravel(), 1),
              ("offsets", "Int64", np.arange(3, 3 * len(mesh.faces) + 1, 3, dtype="<i8"), 1)]
    compress = mode in ("zlib", "vtk9")
    header_type = "UInt64" if mode == "vtk9" else "UInt32"
    header = "<u8" if mode == "vtk9" else "<u4"
    compressor = ' compressor="vtkZLibDataCompressor"' if compress else ""
    body, appended, offset = [], b"", 0
    for name, kind, data, components in arrays:
        attrs = f'type="{kind}" NumberOfComponents="{components}"' + ("" if name == "Points" else f' Name="{name}"')
        if mode == "ascii":
            text = " ".join(repr(float(x)) if kind == "Float32" else str(int(x)) for x in data.ravel())
            body.append(f'<DataArray {attrs} format="ascii">{text}</DataArray>')
        elif mode in ("appended", "vtk9"):
            head, payload = _vtk_block(data, compress, header)
            body.append(f'<DataArray {attrs} format="appended" offset="{offset}"/>')
            appended += head + payload
            offset += len(head) + len(payload)
        else:
            head, payload = _vtk_block(data, compress, header)
            encoded = (base64.b64encode(head) + base64.b64encode(payload)) if compress else \
                base64.b64encode(head + payload)
            body.append(f'<DataArray {attrs} format="binary">{encoded.decode()}</DataArray>')
    version = "2.2" if mode == "vtk9" else "1.0"
    field = ('<FieldData><DataArray type="Float64" Name="TimeValue" NumberOfTuples="1" format="ascii">0'
             "</DataArray></FieldData>\n") if mode == "vtk9" else ""
    xml = (f'<?xml version="1.0"?>\n<VTKFile type="PolyData" version="{version}" byte_order="LittleEndian" '
           f'header_type="{header_type}"{compressor}>\n<PolyData>\n{field}<Piece NumberOfPoints="{len(mesh.vertices)}" '
           f'NumberOfVerts="0" NumberOfLines="0" NumberOfStrips="0" NumberOfPolys="{len(mesh.faces)}">\n'
           f'<PointData Normals="n"><DataArray type="Float32" Name="n" NumberOfComponents="3" format="ascii">'
           f'{" ".join("0 0 1" for _ in mesh.vertices)}</DataArray></PointData>\n'
           f"<Points>{body[0]}</Points>\n<Verts/>\n<Polys>{body[1]}{body[2]}</Polys>\n</Piece>\n</PolyData>\n")
    if appended:
        Path(path).write_bytes(xml.encode() + b'<AppendedData encoding="raw">\n_' + appended +
                               b"\n</AppendedData>\n</VTKFile>\n")
    else:
        Path(path).write_text(xml + "</VTKFile>\n")


def write_gltf(path: Path, mesh: trimesh.Trimesh, embed: bool = False) -> list[Path]:
    """JSON glTF by trimesh's writer: ``path`` and its buffer files beside it (or buffers as data URIs)."""
    scene = trimesh.Scene()
    scene.add_geometry(mesh, node_name="surface", geom_name="surface")
    files = trimesh.exchange.gltf.export_gltf(scene, embed_buffers=embed)
    written = []
    for name, data in files.items():
        target = Path(path) if name.endswith(".gltf") else Path(path).parent / name
        target.write_bytes(data)
        written.append(target)
    return written


def write_surface(path: Path, mesh: trimesh.Trimesh) -> None:
    """``mesh`` in the format of ``path``'s suffix; ``.vtk`` is POLYDATA, ``_ug.vtk`` an unstructured grid;
    ``_binary.vtp`` / ``_appended.vtp`` / ``_zlib.vtp`` / ``_vtk9.vtp`` the XML PolyData encodings;
    ``_embed.gltf`` a glTF with data-URI buffers (else beside it); ``_v22.vtu`` meshio's .vtu stamped 2.2."""
    path = Path(path)
    name = path.name
    if name.endswith("_ug.vtk"):
        meshio.Mesh(mesh.vertices, [("triangle", mesh.faces)]).write(path, file_format="vtk", binary=False)
    elif name.endswith(".vtk"):
        write_polydata(path, mesh)
    elif name.endswith("_v22.vtu"):  # meshio's .vtu stamped as VTK 9 stamps it (version 2.2)
        meshio.Mesh(mesh.vertices, [("triangle", mesh.faces)]).write(path, file_format="vtu")
        path.write_bytes(path.read_bytes().replace(b'version="0.1"', b'version="2.2"', 1))
    elif name.endswith(".vtp"):
        write_vtp(path, mesh, name.rsplit("_", 1)[-1][:-4] if "_" in name else "ascii")
    elif name.endswith(".gltf"):
        write_gltf(path, mesh, embed="embed" in name)
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
