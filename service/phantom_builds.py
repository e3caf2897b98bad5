"""Phantom builds (``pb-`` + 16 hex): a zip of anatomy files + a build manifest, built by the anatomy
pipeline (:mod:`raytrace.body.anatomy`) as a job on the service's one job queue (:mod:`service.jobs`).

A job is a directory under ``<data_dir>/phantom_builds/``::

    job.json     the archive's manifest name, the owner (API key id), created_at
    state.json   state, progress (0-1) and what is being done, the phantom id once stored, the error
    files/       the archive's files (removed when the job ends)
    report.json  the build report (when done)

Everything that can be checked before decoding a mesh is checked before the 202 (docs/phantoms.md,
"Over HTTP"), each refusal a 4xx naming the zip entry or manifest entry: the archive (a zip, at most
``MAX_ENTRIES`` entries, no absolute names, no ``..``, no links, its files' declared sizes together at most
:func:`limits_for`'s bound, each entry's compression ratio at most ``MAX_RATIO``), the manifest (YAML or
JSON at the archive's top, or in its only top directory), every file it names present in the archive, the
volume's voxel count from its header, the build's memory estimate. The build itself runs in the runner's
thread; when it ends the phantom is stored like an upload (atomically, under the uploads' count cap) and
the job's ``phantom_id`` names it, or the job fails with the pipeline's refusal (``error``: ``loc`` and
``msg`` as a 422 would carry them). A job interrupted by a restart builds again from its files.
"""

from __future__ import annotations

import json
import logging
import os
import shutil
import stat
import threading
import time
import zipfile
from pathlib import Path, PurePosixPath
from typing import Any

from raytrace.body.anatomy import Limits, build_phantom, check_limits, load_manifest, parse_manifest_text
from raytrace.body.gltf import export_glb, export_manifest
from raytrace.errors import CapsuleRTError
from service.admission import Cost, admit
from service.errors import Unprocessable, UploadTooLarge, field_to_loc
from service.jobs import CANCEL_FILE, JobKind, JobRunner
from service.registry import Registry, describe_phantom
from service.settings import Settings
from service.storage import Full, new_upload_id
from sweeps.store import atomic_write

log = logging.getLogger("capsule_rt.jobs")

JOB_FILE = "job.json"
STATE_FILE = "state.json"
FILES_DIR = "files"
REPORT_FILE = "report.json"
MANIFEST_NAMES = ("manifest.yaml", "manifest.yml", "manifest.json")
MAX_ENTRIES = 512
#: An entry whose uncompressed size is more than this many times its compressed size is refused (a zip bomb).
MAX_RATIO = 200
#: How often the running job's state is rewritten at most [s].
PUBLISH_S = 0.5


class _Cancelled(Exception):
    pass


def limits_for(settings: Settings) -> Limits:
    """The build limits of this server (docs/phantoms.md, "Limits"), from its settings: files as large as
    8 uploads together, output triangles as an upload's, input triangles 8 times that, and the voxels, grid
    cells and memory of one computation's memory share."""
    share = settings.compute_memory_share_bytes
    return Limits(max_file_bytes=8 * settings.max_upload_bytes, max_total_bytes=8 * settings.max_upload_bytes,
                  max_input_triangles=8 * settings.max_triangles, max_voxels=share // 16,
                  max_grid_cells=share // 48, max_output_triangles=settings.max_triangles, max_memory_bytes=share)


class PhantomBuilds(JobKind):
    kind = "phantom_build"
    prefix = "pb-"
    noun = "phantom build"
    list_path = "/v1/phantoms/builds"
    id_loc = ["path", "build_id"]

    def __init__(self, settings: Settings, registry: Registry, runner: JobRunner) -> None:
        super().__init__(runner, settings, Path(settings.data_dir) / "phantom_builds", settings.sweep_max_queue)
        self.registry = registry
        self.limits = limits_for(settings)

    # ------------------------------------------------------------ the queue's hooks
    def exists(self, d: Path) -> bool:
        return (d / JOB_FILE).is_file()

    def read_state(self, d: Path) -> dict[str, Any]:
        try:
            return json.loads((d / STATE_FILE).read_text())
        except FileNotFoundError:
            return {}

    def write_state(self, d: Path, state: dict[str, Any]) -> None:
        atomic_write(d / STATE_FILE, json.dumps({**state, "updated_at": time.time()}, sort_keys=True).encode())

    def created_at(self, d: Path) -> float:
        return json.loads((d / JOB_FILE).read_text()).get("created_at") or 0

    # ------------------------------------------------------------ submission
    def submit(self, archive: bytes, owner: str | None) -> dict[str, Any]:
        """Check the archive and its manifest (module docstring), store the job ``queued``; its status.
        Runs in a worker thread."""
        with self.admission():
            job_id = self.new_id()
            tmp = self.root / f".tmp-{job_id}"
            try:
                files = tmp / FILES_DIR
                files.mkdir(parents=True)
                manifest_path = _extract(archive, files, self.limits.max_total_bytes)
                try:
                    data = parse_manifest_text(manifest_path.read_bytes(), filename=manifest_path.name)
                    manifest = load_manifest(data)
                    plan = check_limits(manifest, manifest_path.parent, self.limits, confine=True)
                except CapsuleRTError as exc:
                    raise Unprocessable(exc.reason, loc=["body", "archive", *field_to_loc(exc.field)]) from None
                admit(self.estimate(plan), self.settings)  # the one rule (the build's own check said the same)
                record = {"manifest": str(manifest_path.relative_to(files)), "name": manifest.name,
                          "owner": owner, "created_at": time.time()}
                atomic_write(tmp / JOB_FILE, json.dumps(record, sort_keys=True).encode())
                self.write_state(tmp, {"state": "queued", "progress": 0.0, "message": "queued"})
                os.replace(tmp, self.root / job_id)
            except BaseException:
                shutil.rmtree(tmp, ignore_errors=True)
                raise
        log.info("phantom build queued", extra={"phantom_build": job_id})
        return self.status(job_id)

    def estimate(self, plan: dict[str, Any]) -> Cost:
        """A build's cost (service.admission), from the anatomy pipeline's plan of the archive
        (raytrace.body.anatomy.check_limits, before any mesh is decoded): its memory estimate (12 bytes per
        file byte, 10 per voxel) against one computation's share."""
        return Cost(memory=((("archive",), float(plan["memory_estimate_bytes"])),),
                    what=f"the build ({plan['file_bytes']} file bytes, {plan['voxels']} voxels)")

    def owner(self, job_id: str) -> str | None:
        """The submitting key's id, kept in the job's record."""
        return json.loads((self.job_dir(job_id) / JOB_FILE).read_text()).get("owner")

    # ------------------------------------------------------------ API
    def status(self, job_id: str) -> dict[str, Any]:
        d = self.job_dir(job_id)
        job, state = json.loads((d / JOB_FILE).read_text()), self.read_state(d)
        report = None
        if (d / REPORT_FILE).is_file():
            report = json.loads((d / REPORT_FILE).read_text())
        return {"id": job_id, "name": job.get("name", ""), "state": state.get("state", "queued"),
                "progress": float(state.get("progress") or 0.0), "message": state.get("message", ""),
                "phantom_id": state.get("phantom_id"), "error": state.get("error"),
                "created_at": job.get("created_at"), "started_at": state.get("started_at"),
                "finished_at": state.get("finished_at"), "cancel_requested": (d / CANCEL_FILE).exists(),
                "report": report}

    def list(self) -> list[dict[str, Any]]:
        out = []
        for job_id in self.job_ids():
            s = self.status(job_id)
            out.append({k: s[k] for k in ("id", "name", "state", "progress", "phantom_id", "created_at")})
        return sorted(out, key=lambda s: s["created_at"] or 0)

    # ------------------------------------------------------------ runner
    def execute(self, job_id: str, cancel: threading.Event) -> str:
        d = self.root / job_id
        job = json.loads((d / JOB_FILE).read_text())
        state: dict[str, Any] = {"state": "running", "progress": 0.0, "message": "starting", "error": None,
                                 "started_at": time.time(), "finished_at": None, "phantom_id": None}
        last = [0.0]

        def progress(fraction: float, message: str) -> None:
            if cancel.is_set():
                raise _Cancelled()
            state.update(progress=round(float(fraction), 3), message=message)
            now = time.monotonic()
            if now - last[0] >= PUBLISH_S:
                last[0] = now
                self.write_state(d, state)

        self.write_state(d, state)
        manifest_path = d / FILES_DIR / job["manifest"]
        try:
            data = parse_manifest_text(manifest_path.read_bytes(), filename=manifest_path.name)
            result = build_phantom(data, manifest_path.parent, limits=self.limits, confine=True, progress=progress)
            progress(1.0, "storing")
            phantom_id = new_upload_id()
            glb = export_glb(result.phantom)
            manifest = export_manifest(result.phantom)
            info = describe_phantom(phantom_id, result.phantom, builtin=False)
            self.registry.store.save(phantom_id, glb, manifest, info, max_count=self.settings.max_uploads,
                                     owner=job.get("owner"))
            self.registry.remember(phantom_id, result.phantom)
            atomic_write(d / REPORT_FILE, json.dumps(result.report, sort_keys=True, default=float).encode())
            state.update(state="done", progress=1.0, message="built", phantom_id=phantom_id)
        except _Cancelled:
            state.update(state="cancelled", message="cancelled")
        except CapsuleRTError as exc:
            state.update(state="failed", error={"loc": ["body", "archive", *field_to_loc(exc.field)],
                                                "msg": exc.reason})
        except Full as exc:
            state.update(state="failed", error={"loc": ["body", "archive"], "msg": f"{exc}; delete one first"})
        except Exception as exc:  # a bug: recorded, never half-stored
            log.exception("phantom build failed", extra={"phantom_build": job_id})
            state.update(state="failed", error={"loc": ["server"], "msg": f"{type(exc).__name__}: {exc}"})
        state["finished_at"] = time.time()
        self.write_state(d, state)
        shutil.rmtree(d / FILES_DIR, ignore_errors=True)
        return state["state"]


def _extract(archive: bytes, into: Path, max_total_bytes: int) -> Path:
    """Unpack a zip into ``into`` after checking every entry (module docstring); the manifest's path."""
    import io

    try:
        zf = zipfile.ZipFile(io.BytesIO(archive))
    except (zipfile.BadZipFile, ValueError) as exc:
        raise Unprocessable(f"the archive is not a zip file: {exc}", loc=["body", "archive"]) from None
    with zf:
        infos = zf.infolist()
        if len(infos) > MAX_ENTRIES:
            raise Unprocessable(f"the archive holds {len(infos)} entries, over the cap of {MAX_ENTRIES}",
                                loc=["body", "archive"])
        total = 0
        names: list[tuple[zipfile.ZipInfo, PurePosixPath]] = []
        for info in infos:
            name = info.filename
            path = PurePosixPath(name)
            where = ["body", "archive", name]
            if name.startswith("/") or "\\" in name or any(p in ("..", "") for p in path.parts) or ":" in name:
                raise Unprocessable(f"entry {name!r}: absolute names, '..' and drive letters are not allowed",
                                    loc=where)
            mode = info.external_attr >> 16
            if stat.S_ISLNK(mode):
                raise Unprocessable(f"entry {name!r} is a link: only files and directories", loc=where)
            if info.is_dir():
                continue
            if info.flag_bits & 0x1:
                raise Unprocessable(f"entry {name!r} is encrypted", loc=where)
            total += info.file_size
            if total > max_total_bytes:
                raise UploadTooLarge(f"the archive's files hold more than {max_total_bytes} bytes uncompressed "
                                     "(the cap)", loc=where)
            if info.file_size > MAX_RATIO * max(info.compress_size, 1) and info.file_size > 2**20:
                raise Unprocessable(f"entry {name!r} expands {info.file_size / max(info.compress_size, 1):.0f} "
                                    f"times (more than {MAX_RATIO}): refused as a zip bomb", loc=where)
            names.append((info, path))
        for info, path in names:
            target = into.joinpath(*path.parts)
            target.parent.mkdir(parents=True, exist_ok=True)
            try:  # zipfile reads at most the declared size and checks the CRC
                with zf.open(info) as src, open(target, "wb") as dst:
                    shutil.copyfileobj(src, dst, 1 << 20)
            except (zipfile.BadZipFile, NotImplementedError, EOFError, OSError) as exc:
                raise Unprocessable(f"entry {info.filename!r} cannot be unpacked: {exc}",
                                    loc=["body", "archive", info.filename]) from None
    tops = [p for p in into.iterdir()]
    candidates = [into / n for n in MANIFEST_NAMES if (into / n).is_file()]
    if not candidates and len(tops) == 1 and tops[0].is_dir():
        candidates = [tops[0] / n for n in MANIFEST_NAMES if (tops[0] / n).is_file()]
    if len(candidates) != 1:
        raise Unprocessable(f"the archive needs exactly one build manifest ({', '.join(MANIFEST_NAMES)}) at its top "
                            "(or in its only top directory)", loc=["body", "archive"])
    return candidates[0]

