"""Typed HTTP client of the CapsuleRT API (sync :class:`Client` and async :class:`AsyncClient`).

Each method mirrors one endpoint, takes a request model (or a plain dict,
validated locally first) and returns the response model. An error answer
raises :class:`APIError` carrying the status, the ``detail`` list and the
``Retry-After`` header::

    from service.client import Client
    with Client("http://127.0.0.1:8000") as api:
        tissues = api.tissues(402e6)
        ch = api.channel({"scenario": "thesis-fig-5-6", "rays": 20000})
        toa = api.ranging_toa({"profile": ch.profiles[0].model_dump(), "method": "gcc"})

``api_key=...`` sends ``X-API-Key`` with every request (a server with
``CAPSULE_RT_API_KEYS`` set needs it for uploads, jobs and deletes).
"""

from __future__ import annotations

import asyncio
import json
import time
from dataclasses import dataclass
from typing import Any, Generic, TypeVar

import httpx
from pydantic import BaseModel

from service.schemas import Health, Readiness
from service.schemas import localize as loc
from service.schemas import vision as v
from service.schemas.channel import ChannelRequest, ChannelResponse
from service.schemas.fullwave import FullwaveList, FullwaveRequest, FullwaveStatus
from service.schemas.phantoms import (
    Manifest,
    PhantomOut,
    PhantomsResponse,
    ScenariosResponse,
    TissuesResponse,
    UploadResponse,
)
from service.schemas.ranging import (
    PdoaBoundRequest,
    PdoaBoundResponse,
    PdoaRequest,
    RangingResponse,
    RssBoundRequest,
    RssBoundResponse,
    RssRequest,
    ToaBoundRequest,
    ToaBoundResponse,
    ToaRequest,
)

M = TypeVar("M", bound=BaseModel)


class APIError(Exception):
    """A 4xx/5xx answer: ``status``, ``detail`` (list of {loc, msg, type}), ``retry_after_s``."""

    def __init__(self, status: int, detail: Any, retry_after_s: float | None = None, request_id: str | None = None):
        self.status = status
        self.detail = detail
        self.retry_after_s = retry_after_s
        self.request_id = request_id
        super().__init__(f"HTTP {status}: {detail}")

    @property
    def fields(self) -> list[list]:
        """The ``loc`` of every error item."""
        return [item.get("loc", []) for item in self.detail] if isinstance(self.detail, list) else []


@dataclass
class _Call(Generic[M]):
    method: str
    path: str
    model: type[M] | None
    kwargs: dict[str, Any]
    raw: bool = False


def _with_key(api_key: str | None, httpx_kwargs: dict[str, Any]) -> dict[str, Any]:
    """httpx options with the API key (uploads, jobs and deletes on a server that requires keys)."""
    if api_key is None:
        return httpx_kwargs
    return {**httpx_kwargs, "headers": {**dict(httpx_kwargs.get("headers") or {}), "X-API-Key": api_key}}


def _body(model: type[BaseModel], req: BaseModel | dict) -> dict[str, Any]:
    obj = req if isinstance(req, model) else model.model_validate(req)
    return json.loads(obj.model_dump_json(exclude_unset=True))


def _parse(call: _Call, response: httpx.Response):
    if response.status_code >= 400:
        try:
            detail = response.json().get("detail")
        except ValueError:
            detail = response.text
        retry = response.headers.get("retry-after")
        raise APIError(
            response.status_code,
            detail,
            float(retry) if retry and retry.replace(".", "", 1).isdigit() else None,
            response.headers.get("x-request-id"),
        )
    if call.raw:
        return response.content if call.model is None else response.text
    if call.model is None:
        return None
    if call.model is dict:
        return response.json()
    return call.model.model_validate(response.json())


class _Endpoints:
    """Request builders shared by the sync and async clients."""

    @staticmethod
    def healthz() -> _Call:
        return _Call("GET", "/healthz", Health, {})

    @staticmethod
    def readyz() -> _Call:
        return _Call("GET", "/readyz", Readiness, {})

    @staticmethod
    def metrics() -> _Call:
        return _Call("GET", "/metrics", str, {}, raw=True)  # type: ignore[arg-type]

    @staticmethod
    def tissues(frequency_hz: float) -> _Call:
        return _Call("GET", "/v1/tissues", TissuesResponse, {"params": {"frequency_hz": repr(float(frequency_hz))}})

    @staticmethod
    def scenarios() -> _Call:
        return _Call("GET", "/v1/scenarios", ScenariosResponse, {})

    @staticmethod
    def phantoms() -> _Call:
        return _Call("GET", "/v1/phantoms", PhantomsResponse, {})

    @staticmethod
    def phantom(phantom_id: str) -> _Call:
        return _Call("GET", f"/v1/phantoms/{phantom_id}", PhantomOut, {})

    @staticmethod
    def phantom_mesh(phantom_id: str) -> _Call:
        return _Call("GET", f"/v1/phantoms/{phantom_id}/mesh", None, {}, raw=True)

    @staticmethod
    def phantom_manifest(phantom_id: str) -> _Call:
        return _Call("GET", f"/v1/phantoms/{phantom_id}/manifest", dict, {})  # type: ignore[arg-type]

    @staticmethod
    def delete_phantom(phantom_id: str) -> _Call:
        return _Call("DELETE", f"/v1/phantoms/{phantom_id}", None, {})

    @staticmethod
    def upload_phantom(mesh_glb: bytes, manifest: dict | Manifest | str | bytes,
                       filename: str = "phantom.glb") -> _Call:
        if isinstance(manifest, Manifest):
            manifest = manifest.model_dump_json(exclude_none=True)
        elif isinstance(manifest, dict):
            manifest = json.dumps(manifest)
        files = {
            "mesh": (filename, mesh_glb, "model/gltf-binary"),
            "manifest": ("manifest.json", manifest, "application/json"),
        }
        return _Call("POST", "/v1/phantoms", UploadResponse, {"files": files})

    @staticmethod
    def channel(req: ChannelRequest | dict) -> _Call:
        return _Call("POST", "/v1/channel", ChannelResponse, {"json": _body(ChannelRequest, req)})

    @staticmethod
    def ranging_toa(req: ToaRequest | dict) -> _Call:
        return _Call("POST", "/v1/ranging/toa", RangingResponse, {"json": _body(ToaRequest, req)})

    @staticmethod
    def ranging_pdoa(req: PdoaRequest | dict) -> _Call:
        return _Call("POST", "/v1/ranging/pdoa", RangingResponse, {"json": _body(PdoaRequest, req)})

    @staticmethod
    def ranging_rss(req: RssRequest | dict) -> _Call:
        return _Call("POST", "/v1/ranging/rss", RangingResponse, {"json": _body(RssRequest, req)})

    @staticmethod
    def localize(req: loc.LocalizeRequest | dict) -> _Call:
        return _Call("POST", "/v1/localize", loc.LocalizeResponse, {"json": _body(loc.LocalizeRequest, req)})

    @staticmethod
    def localize_evaluate(req: loc.LocalizeEvaluateRequest | dict) -> _Call:
        return _Call("POST", "/v1/localize/evaluate", loc.LocalizeEvaluateResponse,
                     {"json": _body(loc.LocalizeEvaluateRequest, req)})

    @staticmethod
    def bound_toa(req: ToaBoundRequest | dict) -> _Call:
        return _Call("POST", "/v1/bounds/toa", ToaBoundResponse, {"json": _body(ToaBoundRequest, req)})

    @staticmethod
    def bound_pdoa(req: PdoaBoundRequest | dict) -> _Call:
        return _Call("POST", "/v1/bounds/pdoa", PdoaBoundResponse, {"json": _body(PdoaBoundRequest, req)})

    @staticmethod
    def bound_rss(req: RssBoundRequest | dict) -> _Call:
        return _Call("POST", "/v1/bounds/rss", RssBoundResponse, {"json": _body(RssBoundRequest, req)})

    @staticmethod
    def vision_render(req: v.RenderRequest | dict) -> _Call:
        return _Call("POST", "/v1/vision/render", v.RenderResponse,
                     {"json": _body(v.RenderRequest, req), "headers": {"Accept": "application/json"}})

    @staticmethod
    def vision_render_png(req: v.RenderRequest | dict) -> _Call:
        return _Call("POST", "/v1/vision/render", None,
                     {"json": _body(v.RenderRequest, req), "headers": {"Accept": "image/png"}}, raw=True)

    @staticmethod
    def vision_motion(reference_png: bytes, moving_png: bytes, options: v.MotionOptions | dict | None = None,
                      geometry: v.RenderRequest | dict | None = None) -> _Call:
        files: dict[str, Any] = {"reference": ("reference.png", reference_png, "image/png"),
                                 "moving": ("moving.png", moving_png, "image/png")}
        for name, model, value in (("options", v.MotionOptions, options), ("geometry", v.RenderRequest, geometry)):
            if value is not None:
                files[name] = (f"{name}.json", json.dumps(_body(model, value)), "application/json")
        return _Call("POST", "/v1/vision/motion", v.MotionResponse, {"files": files})

    @staticmethod
    def fullwave_submit(req: dict | BaseModel) -> _Call:
        return _Call("POST", "/v1/fullwave", FullwaveStatus, {"json": _body(FullwaveRequest, req)})

    @staticmethod
    def fullwave_status(job_id: str) -> _Call:
        return _Call("GET", f"/v1/fullwave/{job_id}", FullwaveStatus, {})

    @staticmethod
    def fullwave_jobs() -> _Call:
        return _Call("GET", "/v1/fullwave", FullwaveList, {})

    @staticmethod
    def fullwave_report(job_id: str, format: str) -> _Call:
        if format == "json":
            return _Call("GET", f"/v1/fullwave/{job_id}/report", dict, {"params": {"format": "json"}})
        return _Call("GET", f"/v1/fullwave/{job_id}/report", str, {"params": {"format": format}}, raw=True)

    @staticmethod
    def fullwave_file(job_id: str, name: str) -> _Call:
        return _Call("GET", f"/v1/fullwave/{job_id}/files/{name}", None, {}, raw=True)

    @staticmethod
    def fullwave_cancel(job_id: str) -> _Call:
        return _Call("DELETE", f"/v1/fullwave/{job_id}", FullwaveStatus, {})


#: States a full-wave job (or a sweep) does not leave.
FINISHED = ("done", "failed", "cancelled")


class Client:
    """Synchronous client. ``Client(base_url, timeout=..., transport=...)``; a context manager."""

    def __init__(self, base_url: str = "http://127.0.0.1:8000", *, timeout: float = 120.0,
                 api_key: str | None = None, **httpx_kwargs: Any):
        self._http = httpx.Client(base_url=base_url, timeout=timeout, **_with_key(api_key, httpx_kwargs))

    def close(self) -> None:
        self._http.close()

    def __enter__(self) -> "Client":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def _do(self, call: _Call, headers: dict[str, str] | None = None):
        kwargs = dict(call.kwargs)
        headers = {**kwargs.pop("headers", {}), **(headers or {})} or None
        return _parse(call, self._http.request(call.method, call.path, headers=headers, **kwargs))

    def healthz(self, *, headers: dict[str, str] | None = None) -> Health:
        return self._do(_Endpoints.healthz(), headers)

    def readyz(self, *, headers: dict[str, str] | None = None) -> Readiness:
        return self._do(_Endpoints.readyz(), headers)

    def metrics(self, *, headers: dict[str, str] | None = None) -> str:
        return self._do(_Endpoints.metrics(), headers)

    def tissues(self, frequency_hz: float, *, headers: dict[str, str] | None = None) -> TissuesResponse:
        return self._do(_Endpoints.tissues(frequency_hz), headers)

    def scenarios(self, *, headers: dict[str, str] | None = None) -> ScenariosResponse:
        return self._do(_Endpoints.scenarios(), headers)

    def phantoms(self, *, headers: dict[str, str] | None = None) -> PhantomsResponse:
        return self._do(_Endpoints.phantoms(), headers)

    def phantom(self, phantom_id: str, *, headers: dict[str, str] | None = None) -> PhantomOut:
        return self._do(_Endpoints.phantom(phantom_id), headers)

    def phantom_mesh(self, phantom_id: str, *, headers: dict[str, str] | None = None) -> bytes:
        return self._do(_Endpoints.phantom_mesh(phantom_id), headers)

    def phantom_manifest(self, phantom_id: str, *, headers: dict[str, str] | None = None) -> dict:
        return self._do(_Endpoints.phantom_manifest(phantom_id), headers)

    def delete_phantom(self, phantom_id: str, *, headers: dict[str, str] | None = None) -> None:
        return self._do(_Endpoints.delete_phantom(phantom_id), headers)

    def upload_phantom(self, mesh_glb: bytes, manifest: dict | Manifest | str | bytes, filename: str = "phantom.glb",
                       *, headers: dict[str, str] | None = None) -> UploadResponse:
        return self._do(_Endpoints.upload_phantom(mesh_glb, manifest, filename), headers)

    def channel(self, req: ChannelRequest | dict, *, headers: dict[str, str] | None = None) -> ChannelResponse:
        return self._do(_Endpoints.channel(req), headers)

    def ranging_toa(self, req: ToaRequest | dict, *, headers: dict[str, str] | None = None) -> RangingResponse:
        return self._do(_Endpoints.ranging_toa(req), headers)

    def ranging_pdoa(self, req: PdoaRequest | dict, *, headers: dict[str, str] | None = None) -> RangingResponse:
        return self._do(_Endpoints.ranging_pdoa(req), headers)

    def ranging_rss(self, req: RssRequest | dict, *, headers: dict[str, str] | None = None) -> RangingResponse:
        return self._do(_Endpoints.ranging_rss(req), headers)

    def localize(self, req: loc.LocalizeRequest | dict, *,
                 headers: dict[str, str] | None = None) -> loc.LocalizeResponse:
        """POST /v1/localize: one position fix from the sensors' ranges, delays or received powers."""
        return self._do(_Endpoints.localize(req), headers)

    def localize_evaluate(self, req: loc.LocalizeEvaluateRequest | dict, *,
                          headers: dict[str, str] | None = None) -> loc.LocalizeEvaluateResponse:
        """POST /v1/localize/evaluate: trace, range and locate; error statistics beside the bound."""
        return self._do(_Endpoints.localize_evaluate(req), headers)

    def bound_toa(self, req: ToaBoundRequest | dict, *, headers: dict[str, str] | None = None) -> ToaBoundResponse:
        return self._do(_Endpoints.bound_toa(req), headers)

    def bound_pdoa(self, req: PdoaBoundRequest | dict, *, headers: dict[str, str] | None = None) -> PdoaBoundResponse:
        return self._do(_Endpoints.bound_pdoa(req), headers)

    def bound_rss(self, req: RssBoundRequest | dict, *, headers: dict[str, str] | None = None) -> RssBoundResponse:
        return self._do(_Endpoints.bound_rss(req), headers)

    def vision_render(self, req: v.RenderRequest | dict, *, headers: dict[str, str] | None = None) -> v.RenderResponse:
        """The frame and its exact pose (JSON: ``.image_png_base64``, ``.pose``, ``.camera``)."""
        return self._do(_Endpoints.vision_render(req), headers)

    def vision_render_png(self, req: v.RenderRequest | dict, *, headers: dict[str, str] | None = None) -> bytes:
        """The frame's PNG bytes only."""
        return self._do(_Endpoints.vision_render_png(req), headers)

    def vision_motion(self, reference_png: bytes, moving_png: bytes, options: v.MotionOptions | dict | None = None,
                      geometry: v.RenderRequest | dict | None = None, *,
                      headers: dict[str, str] | None = None) -> v.MotionResponse:
        """Rotation, scale (and advance, with the reference's render request as ``geometry``)."""
        return self._do(_Endpoints.vision_motion(reference_png, moving_png, options, geometry), headers)

    def fullwave_submit(self, req: FullwaveRequest | dict, *,  # type: ignore[valid-type]
                        headers: dict[str, str] | None = None) -> FullwaveStatus:
        """POST /v1/fullwave: queue a full-wave cross-check (a channel request + FDTD options); its status."""
        return self._do(_Endpoints.fullwave_submit(req), headers)

    def fullwave_status(self, job_id: str, *, headers: dict[str, str] | None = None) -> FullwaveStatus:
        return self._do(_Endpoints.fullwave_status(job_id), headers)

    def fullwave_jobs(self, *, headers: dict[str, str] | None = None) -> FullwaveList:
        return self._do(_Endpoints.fullwave_jobs(), headers)

    def fullwave_wait(self, job_id: str, *, poll_s: float = 1.0, timeout_s: float | None = None,
                      headers: dict[str, str] | None = None) -> FullwaveStatus:
        """Poll the job until it is done, failed or cancelled; its last status (``TimeoutError`` after
        ``timeout_s``)."""
        deadline = None if timeout_s is None else time.monotonic() + timeout_s
        while True:
            status = self.fullwave_status(job_id, headers=headers)
            if status.state in FINISHED:
                return status
            if deadline is not None and time.monotonic() > deadline:
                raise TimeoutError(f"full-wave job {job_id} is still {status.state} after {timeout_s} s")
            time.sleep(poll_s)

    def fullwave_report(self, job_id: str, format: str = "json", *,
                        headers: dict[str, str] | None = None) -> dict | str:
        """The report of a done job: a dict (``json``) or Markdown text (``md``)."""
        return self._do(_Endpoints.fullwave_report(job_id, format), headers)

    def fullwave_file(self, job_id: str, name: str, *, headers: dict[str, str] | None = None) -> bytes:
        """One of the files its status lists (``model_20.in``, ``model_20.h5``, ``report.md``, ...)."""
        return self._do(_Endpoints.fullwave_file(job_id, name), headers)

    def fullwave_cancel(self, job_id: str, *, headers: dict[str, str] | None = None) -> FullwaveStatus:
        """Cancel a queued or running job (gprMax is killed); delete a finished one."""
        return self._do(_Endpoints.fullwave_cancel(job_id), headers)


class AsyncClient:
    """Asynchronous client (same methods, awaitable)."""

    def __init__(self, base_url: str = "http://127.0.0.1:8000", *, timeout: float = 120.0,
                 api_key: str | None = None, **httpx_kwargs: Any):
        self._http = httpx.AsyncClient(base_url=base_url, timeout=timeout, **_with_key(api_key, httpx_kwargs))

    async def aclose(self) -> None:
        await self._http.aclose()

    async def __aenter__(self) -> "AsyncClient":
        return self

    async def __aexit__(self, *exc) -> None:
        await self.aclose()

    async def _do(self, call: _Call, headers: dict[str, str] | None = None):
        kwargs = dict(call.kwargs)
        headers = {**kwargs.pop("headers", {}), **(headers or {})} or None
        return _parse(call, await self._http.request(call.method, call.path, headers=headers, **kwargs))

    async def healthz(self, *, headers: dict[str, str] | None = None) -> Health:
        return await self._do(_Endpoints.healthz(), headers)

    async def readyz(self, *, headers: dict[str, str] | None = None) -> Readiness:
        return await self._do(_Endpoints.readyz(), headers)

    async def metrics(self, *, headers: dict[str, str] | None = None) -> str:
        return await self._do(_Endpoints.metrics(), headers)

    async def tissues(self, frequency_hz: float, *, headers: dict[str, str] | None = None) -> TissuesResponse:
        return await self._do(_Endpoints.tissues(frequency_hz), headers)

    async def scenarios(self, *, headers: dict[str, str] | None = None) -> ScenariosResponse:
        return await self._do(_Endpoints.scenarios(), headers)

    async def phantoms(self, *, headers: dict[str, str] | None = None) -> PhantomsResponse:
        return await self._do(_Endpoints.phantoms(), headers)

    async def phantom(self, phantom_id: str, *, headers: dict[str, str] | None = None) -> PhantomOut:
        return await self._do(_Endpoints.phantom(phantom_id), headers)

    async def phantom_mesh(self, phantom_id: str, *, headers: dict[str, str] | None = None) -> bytes:
        return await self._do(_Endpoints.phantom_mesh(phantom_id), headers)

    async def phantom_manifest(self, phantom_id: str, *, headers: dict[str, str] | None = None) -> dict:
        return await self._do(_Endpoints.phantom_manifest(phantom_id), headers)

    async def delete_phantom(self, phantom_id: str, *, headers: dict[str, str] | None = None) -> None:
        return await self._do(_Endpoints.delete_phantom(phantom_id), headers)

    async def upload_phantom(self, mesh_glb: bytes, manifest: dict | Manifest | str | bytes,
                             filename: str = "phantom.glb", *, headers: dict[str, str] | None = None) -> UploadResponse:
        return await self._do(_Endpoints.upload_phantom(mesh_glb, manifest, filename), headers)

    async def channel(self, req: ChannelRequest | dict, *, headers: dict[str, str] | None = None) -> ChannelResponse:
        return await self._do(_Endpoints.channel(req), headers)

    async def ranging_toa(self, req: ToaRequest | dict, *, headers: dict[str, str] | None = None) -> RangingResponse:
        return await self._do(_Endpoints.ranging_toa(req), headers)

    async def ranging_pdoa(self, req: PdoaRequest | dict, *, headers: dict[str, str] | None = None) -> RangingResponse:
        return await self._do(_Endpoints.ranging_pdoa(req), headers)

    async def ranging_rss(self, req: RssRequest | dict, *, headers: dict[str, str] | None = None) -> RangingResponse:
        return await self._do(_Endpoints.ranging_rss(req), headers)

    async def localize(self, req: loc.LocalizeRequest | dict, *,
                 headers: dict[str, str] | None = None) -> loc.LocalizeResponse:
        """POST /v1/localize: one position fix from the sensors' ranges, delays or received powers."""
        return await self._do(_Endpoints.localize(req), headers)

    async def localize_evaluate(self, req: loc.LocalizeEvaluateRequest | dict, *,
                          headers: dict[str, str] | None = None) -> loc.LocalizeEvaluateResponse:
        """POST /v1/localize/evaluate: trace, range and locate; error statistics beside the bound."""
        return await self._do(_Endpoints.localize_evaluate(req), headers)

    async def bound_toa(self, req: ToaBoundRequest | dict, *,
                        headers: dict[str, str] | None = None) -> ToaBoundResponse:
        return await self._do(_Endpoints.bound_toa(req), headers)

    async def bound_pdoa(self, req: PdoaBoundRequest | dict, *,
                         headers: dict[str, str] | None = None) -> PdoaBoundResponse:
        return await self._do(_Endpoints.bound_pdoa(req), headers)

    async def bound_rss(self, req: RssBoundRequest | dict, *,
                        headers: dict[str, str] | None = None) -> RssBoundResponse:
        return await self._do(_Endpoints.bound_rss(req), headers)

    async def vision_render(self, req: v.RenderRequest | dict, *,
                            headers: dict[str, str] | None = None) -> v.RenderResponse:
        """The frame and its exact pose (JSON: ``.image_png_base64``, ``.pose``, ``.camera``)."""
        return await self._do(_Endpoints.vision_render(req), headers)

    async def vision_render_png(self, req: v.RenderRequest | dict, *,
                                headers: dict[str, str] | None = None) -> bytes:
        """The frame's PNG bytes only."""
        return await self._do(_Endpoints.vision_render_png(req), headers)

    async def vision_motion(self, reference_png: bytes, moving_png: bytes,
                            options: v.MotionOptions | dict | None = None,
                            geometry: v.RenderRequest | dict | None = None, *,
                            headers: dict[str, str] | None = None) -> v.MotionResponse:
        """Rotation, scale (and advance, with the reference's render request as ``geometry``)."""
        return await self._do(_Endpoints.vision_motion(reference_png, moving_png, options, geometry), headers)

    async def fullwave_submit(self, req: FullwaveRequest | dict, *,  # type: ignore[valid-type]
                        headers: dict[str, str] | None = None) -> FullwaveStatus:
        """POST /v1/fullwave: queue a full-wave cross-check (a channel request + FDTD options); its status."""
        return await self._do(_Endpoints.fullwave_submit(req), headers)

    async def fullwave_status(self, job_id: str, *, headers: dict[str, str] | None = None) -> FullwaveStatus:
        return await self._do(_Endpoints.fullwave_status(job_id), headers)

    async def fullwave_jobs(self, *, headers: dict[str, str] | None = None) -> FullwaveList:
        return await self._do(_Endpoints.fullwave_jobs(), headers)

    async def fullwave_wait(self, job_id: str, *, poll_s: float = 1.0, timeout_s: float | None = None,
                      headers: dict[str, str] | None = None) -> FullwaveStatus:
        """Poll the job until it is done, failed or cancelled; its last status (``TimeoutError`` after
        ``timeout_s``)."""
        deadline = None if timeout_s is None else time.monotonic() + timeout_s
        while True:
            status = await self.fullwave_status(job_id, headers=headers)
            if status.state in FINISHED:
                return status
            if deadline is not None and time.monotonic() > deadline:
                raise TimeoutError(f"full-wave job {job_id} is still {status.state} after {timeout_s} s")
            await asyncio.sleep(poll_s)

    async def fullwave_report(self, job_id: str, format: str = "json", *,
                        headers: dict[str, str] | None = None) -> dict | str:
        """The report of a done job: a dict (``json``) or Markdown text (``md``)."""
        return await self._do(_Endpoints.fullwave_report(job_id, format), headers)

    async def fullwave_file(self, job_id: str, name: str, *, headers: dict[str, str] | None = None) -> bytes:
        """One of the files its status lists (``model_20.in``, ``model_20.h5``, ``report.md``, ...)."""
        return await self._do(_Endpoints.fullwave_file(job_id, name), headers)

    async def fullwave_cancel(self, job_id: str, *, headers: dict[str, str] | None = None) -> FullwaveStatus:
        """Cancel a queued or running job (gprMax is killed); delete a finished one."""
        return await self._do(_Endpoints.fullwave_cancel(job_id), headers)
