"""Phantoms: list, describe, upload (.glb + manifest), download mesh, delete."""

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
from service.schemas.phantoms import PhantomOut, PhantomsResponse, UploadResponse
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

_UPLOAD_BODY = {
    "requestBody": {
        "required": True,
        "content": {
            "multipart/form-data": {
                "schema": {
                    "type": "object",
                    "required": ["mesh", "manifest"],
                    "additionalProperties": False,
                    "properties": {
                        "mesh": {
                            "type": "string",
                            "format": "binary",
                            "description": "Binary glTF (.glb) whose mesh nodes are named after the organs.",
                        },
                        "manifest": {
                            "type": "string",
                            "contentMediaType": "application/json",
                            "description": "JSON text of a manifest (schema `#/components/schemas/Manifest`): "
                            "name, units, organs (mesh node name -> tissue or explicit medium), sites.",
                        },
                    },
                },
                "encoding": {"mesh": {"contentType": "model/gltf-binary"},
                             "manifest": {"contentType": "application/json"}},
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
    summary="Upload a phantom: multipart `mesh` (.glb) + `manifest` (JSON)",
    openapi_extra=_UPLOAD_BODY,
    responses=error_responses(400, 401, 403, 413, 422, 503, 504, 507),
)
@declare(body=lambda s: s.max_upload_bytes + s.max_manifest_bytes + MULTIPART_OVERHEAD_BYTES,
         cost="the .glb's triangles, read from its accessors and refused over max_triangles before any geometry "
              "is built (raytrace.body.gltf.load_phantom); the validation is ~5 s of CPU per million", keyed=True)
async def upload_phantom(request: Request) -> JSONResponse:
    """Validated like a built-in (closed, outward-oriented organs that neither cross each
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
