"""Phantoms: list, describe, upload (.glb + manifest, or a zip of anatomy files built as a job), follow a
build, download mesh, delete."""

from __future__ import annotations

import anyio.to_thread
from fastapi import APIRouter, Path, Request, Response
from fastapi.responses import JSONResponse

from raytrace.body.gltf import load_phantom, parse_manifest
from raytrace.solver.budget import Budget
from service.admission import declare
from service.deps import state
from service.errors import Conflict, NotFound, StorageFull, error_responses
from service.registry import describe_phantom
from service.schemas import ID_PATTERN
from service.schemas.phantoms import (
    PhantomBuildList,
    PhantomBuildStatus,
    PhantomOut,
    PhantomsResponse,
    UploadResponse,
)
from service.security import check_owner, writer
from service.storage import Full, Missing, is_upload_id, new_upload_id
from service.uploads import MULTIPART_OVERHEAD_BYTES, read_upload

router = APIRouter(prefix="/v1/phantoms", tags=["phantoms"])

PhantomIdPath = Path(
    ...,
    pattern=ID_PATTERN,
    description="Phantom id: a built-in name (e.g. `torso`) or an upload's `up-<16 hex>`.",
    examples=["torso"],
)

_ARCHIVE_PART = {
    "type": "string",
    "format": "binary",
    "description": "A zip of anatomy files (surfaces: VTK, STL, PLY, OBJ, OFF, glTF; a labelled NIfTI volume; "
    "centreline JSON/CSV) and a build manifest (`manifest.yaml` or `manifest.json`, docs/phantoms.md) at its top.",
}
_MESH_PART = {
    "type": "string",
    "format": "binary",
    "description": "Binary glTF (.glb) whose mesh nodes are named after the organs.",
}
_MANIFEST_PART = {
    "type": "string",
    "contentMediaType": "application/json",
    "description": "JSON text of a manifest (schema `#/components/schemas/Manifest`): name, units, organs (mesh "
    "node name -> tissue or explicit medium), sites.",
}
_UPLOAD_BODY = {
    "requestBody": {
        "required": True,
        "content": {
            "multipart/form-data": {
                "schema": {
                    "description": "Either `mesh` and `manifest` (a ready phantom, stored at once: 201), or "
                    "`archive` alone (anatomy files and a build manifest, built as a job: 202).",
                    "oneOf": [
                        {"type": "object", "required": ["mesh", "manifest"], "additionalProperties": False,
                         "properties": {"mesh": _MESH_PART, "manifest": _MANIFEST_PART}},
                        {"type": "object", "required": ["archive"], "additionalProperties": False,
                         "properties": {"archive": _ARCHIVE_PART}},
                    ],
                },
                "encoding": {"mesh": {"contentType": "model/gltf-binary"},
                             "manifest": {"contentType": "application/json"},
                             "archive": {"contentType": "application/zip"}},
            }
        },
    }
}


@router.get("", response_model=PhantomsResponse, operation_id="list_phantoms", summary="List phantoms")
async def list_phantoms(request: Request) -> PhantomsResponse:
    """Built-in and uploaded phantoms (summaries; GET /v1/phantoms/{id} for organs and sites)."""
    reg = state(request).registry
    summaries = await anyio.to_thread.run_sync(reg.summaries)
    return PhantomsResponse(phantoms=summaries)


BuildIdPath = Path(..., pattern=r"^pb-[0-9a-f]{16}$", description="Build id (`pb-` + 16 hex digits).",
                   examples=["pb-0123456789abcdef"])


def _builds(request: Request):
    return request.app.state.phantom_builds


@router.get("/builds", response_model=PhantomBuildList, operation_id="list_phantom_builds",
            summary="List phantom builds")
async def list_phantom_builds(request: Request) -> PhantomBuildList:
    """Every stored phantom build job, oldest first."""
    return PhantomBuildList(builds=await anyio.to_thread.run_sync(_builds(request).list))


@router.get("/builds/{build_id}", response_model=PhantomBuildStatus, operation_id="get_phantom_build",
            summary="A phantom build's progress, its phantom and its report", responses=error_responses(404, 422))
async def get_phantom_build(request: Request, build_id: str = BuildIdPath) -> PhantomBuildStatus:
    """State (`queued`, `running`, `done`, `failed`, `cancelled`), progress and what is being done; once
    `done` the stored phantom's id (`GET /v1/phantoms/{phantom_id}`, the viewer) and the build report; a
    `failed` build's `error` names the archive's file, organ or label and why (docs/phantoms.md)."""
    return PhantomBuildStatus.model_validate(await anyio.to_thread.run_sync(_builds(request).status, build_id))


@router.delete("/builds/{build_id}", response_model=PhantomBuildStatus, operation_id="cancel_phantom_build",
               summary="Cancel or delete a phantom build", responses=error_responses(401, 403, 404, 409, 422))
@declare(body=None, cost="none: writes a cancellation file, or removes a finished build's record", keyed=True)
async def cancel_phantom_build(request: Request, build_id: str = BuildIdPath) -> PhantomBuildStatus:
    """A queued or running build is cancelled (nothing is stored); a finished one's record is deleted (its
    phantom stays, `DELETE /v1/phantoms/{phantom_id}` removes it)."""
    st = state(request)
    requester = writer(request, st.settings)
    return PhantomBuildStatus.model_validate(await anyio.to_thread.run_sync(_builds(request).cancel, build_id,
                                                                            requester))


@router.get(
    "/{phantom_id}",
    response_model=PhantomOut,
    operation_id="get_phantom",
    summary="Describe a phantom: organs and named sites",
    responses=error_responses(404, 422),
)
async def get_phantom(request: Request, phantom_id: str = PhantomIdPath) -> PhantomOut:
    reg = state(request).registry
    info = await anyio.to_thread.run_sync(reg.info, phantom_id)
    return PhantomOut(**info)


@router.get(
    "/{phantom_id}/mesh",
    operation_id="get_phantom_mesh",
    summary="The phantom as binary glTF (.glb) with organ-named nodes",
    response_class=Response,
    responses={
        200: {"content": {"model/gltf-binary": {"schema": {"type": "string", "format": "binary"}}},
              "description": "The .glb."},
        **error_responses(404, 422),
    },
)
async def get_phantom_mesh(request: Request, phantom_id: str = PhantomIdPath) -> Response:
    """Round-trips through POST /v1/phantoms (with a manifest naming the same organs)."""
    reg = state(request).registry
    glb = await anyio.to_thread.run_sync(reg.mesh_glb, phantom_id)
    return Response(
        glb,
        media_type="model/gltf-binary",
        headers={"Content-Disposition": f'attachment; filename="{phantom_id}.glb"'},
    )


@router.get(
    "/{phantom_id}/manifest",
    operation_id="get_phantom_manifest",
    summary="The manifest that, with the .glb of /mesh, re-uploads the phantom",
    responses={
        200: {"content": {"application/json": {"schema": {"type": "object"}}},
              "description": "The manifest (schema `Manifest`)."},
        **error_responses(404, 422),
    },
)
async def get_phantom_manifest(request: Request, phantom_id: str = PhantomIdPath) -> JSONResponse:
    reg = state(request).registry
    manifest = await anyio.to_thread.run_sync(reg.manifest, phantom_id)
    return JSONResponse(manifest)


@router.delete(
    "/{phantom_id}",
    status_code=204,
    operation_id="delete_phantom",
    summary="Delete an uploaded phantom",
    response_class=Response,
    responses=error_responses(401, 403, 404, 409, 422),
)
@declare(body=None, cost="none: removes the phantom's directory", keyed=True)
async def delete_phantom(request: Request, phantom_id: str = PhantomIdPath) -> Response:
    """Built-in phantoms cannot be deleted (409). When the server requires API keys, only
    the key that uploaded a phantom deletes it (docs/service.md, "Security")."""
    st = state(request)
    reg = st.registry
    requester = writer(request, st.settings)
    if phantom_id in reg.builtins:
        raise Conflict(f"phantom {phantom_id!r} is built in and cannot be deleted", loc=["path", "phantom_id"])
    if not is_upload_id(phantom_id):
        raise NotFound(reg.unknown_message(phantom_id), loc=["path", "phantom_id"])
    if requester is not None:
        try:
            stored_owner = await anyio.to_thread.run_sync(reg.store.owner, phantom_id)
        except Missing:
            raise NotFound(reg.unknown_message(phantom_id), loc=["path", "phantom_id"]) from None
        check_owner(stored_owner, requester, f"phantom {phantom_id!r}")
    removed = await anyio.to_thread.run_sync(reg.store.delete, phantom_id)
    reg.forget(phantom_id)
    if not removed:
        raise NotFound(reg.unknown_message(phantom_id), loc=["path", "phantom_id"])
    return Response(status_code=204)


@router.post(
    "",
    status_code=201,
    response_model=UploadResponse,
    operation_id="upload_phantom",
    summary="Upload a phantom: multipart `mesh` (.glb) + `manifest` (JSON), or an `archive` of anatomy files to build",
    openapi_extra=_UPLOAD_BODY,
    responses={202: {"model": PhantomBuildStatus, "description": "An `archive` was checked and its build queued "
                     "(`Location`: /v1/phantoms/builds/{build_id})."},
               **error_responses(400, 401, 403, 413, 422, 503, 504, 507)},
)
@declare(body=lambda s: s.max_upload_bytes + s.max_manifest_bytes + MULTIPART_OVERHEAD_BYTES,
         cost="a .glb: its triangles, read from its accessors and refused over max_triangles before any geometry "
              "is built (raytrace.body.gltf.load_phantom; ~5 s of CPU per million); an archive: its build's plan "
              "(service.phantom_builds.PhantomBuilds.estimate)", keyed=True)
async def upload_phantom(request: Request) -> JSONResponse:
    """With `archive`: the zip's files and build manifest are checked (sizes, voxels, every named file present,
    the build's memory) and built as a job by the anatomy pipeline (202; follow it at
    `/v1/phantoms/builds/{build_id}`; docs/phantoms.md). With `mesh` + `manifest`: validated like a built-in
    (closed, outward-oriented organs that neither cross each
    other nor themselves; every manifest organ present as a mesh node and vice versa; a
    mesh size that fits its units; sites a channel request accepts; size and triangle
    caps) and stored atomically in the data directory: it survives a restart and is
    never half-written. The body is read as a stream and refused (413) as soon as it
    passes the size cap. Layers are nested solids: a fat layer under the skin is the
    whole solid inside the skin surface, not a shell (docs/service.md, "Uploads")."""
    st = state(request)
    settings = st.settings
    owner = writer(request, settings)
    if st.registry.upload_count() >= settings.max_uploads:  # cheap early answer; enforced at commit
        raise StorageFull(
            f"{settings.max_uploads} uploaded phantoms stored already (the cap); delete one first",
            loc=["body", "mesh"],
        )
    request.scope["capsule_rt.error_loc"] = "body"
    parts = await read_upload(request, settings.max_upload_bytes, settings.max_manifest_bytes)
    if parts.archive is not None:  # anatomy files: checked now, built as a job (docs/phantoms.md, "Over HTTP")
        status = await anyio.to_thread.run_sync(_builds(request).submit, parts.archive, owner)
        return JSONResponse(PhantomBuildStatus.model_validate(status).model_dump(), status_code=202,
                            headers={"Location": f"/v1/phantoms/builds/{status['id']}"})

    def build(budget: Budget):
        manifest = parse_manifest(parts.manifest)
        phantom = load_phantom(
            parts.mesh, manifest, max_bytes=settings.max_upload_bytes, max_triangles=settings.max_triangles
        )
        budget.charge(0)
        phantom_id = new_upload_id()
        info = describe_phantom(phantom_id, phantom, builtin=False)
        try:  # stored as sent: GET .../manifest gives it back
            st.registry.store.save(phantom_id, parts.mesh, manifest, info, max_count=settings.max_uploads, owner=owner)
        except Full as exc:
            raise StorageFull(f"{exc}; delete one first", loc=["body", "mesh"]) from None
        except OSError as exc:  # disk full, permissions...: nothing was left behind (see storage.save)
            raise StorageFull(f"could not store the phantom: {exc.strerror or exc}", loc=["body", "mesh"]) from exc
        return phantom_id, phantom, info

    budget = Budget(deadline_s=settings.request_deadline_s)
    phantom_id, phantom, info = await st.gate.run(build, budget)
    st.registry.remember(phantom_id, phantom)
    return JSONResponse(
        UploadResponse(**info).model_dump(), status_code=201, headers={"Location": f"/v1/phantoms/{phantom_id}"}
    )
