"""Streaming multipart reader for phantom uploads, with size caps enforced while reading.

The request body is read chunk by chunk from the ASGI stream and fed to
python-multipart's streaming parser; a running byte count stops the read
(413) as soon as the body, or one part, passes its cap, so an oversized
upload is never buffered whole. Only the expected parts are kept
(``mesh`` <= ``max_upload_bytes``, ``manifest`` <= ``max_manifest_bytes``; or ``archive`` <=
``max_upload_bytes``, a zip of anatomy files that :mod:`service.phantom_builds` builds). The reader itself
(:func:`read_parts`) serves every multipart operation (the vision frames too).
"""

from __future__ import annotations

from dataclasses import dataclass, field

try:
    from python_multipart.multipart import MultipartParser, parse_options_header
except ImportError:  # python-multipart < 0.0.13 named its module `multipart`
    from multipart.multipart import MultipartParser, parse_options_header  # type: ignore[no-redef]
from starlette.requests import ClientDisconnect, Request

from service.errors import InvalidMesh, Unprocessable, UploadTooLarge

GLB_MAGIC = b"glTF"
MULTIPART_OVERHEAD_BYTES = 16 * 1024


@dataclass
class _Part:
    headers: dict[str, str] = field(default_factory=dict)
    name: str | None = None
    filename: str | None = None
    data: bytearray = field(default_factory=bytearray)


@dataclass
class UploadParts:
    """Either ``mesh`` + ``manifest`` (a ready phantom) or ``archive`` (anatomy files to build)."""

    mesh: bytes = b""
    mesh_filename: str | None = None
    manifest: bytes = b""
    archive: bytes | None = None


def _listing(names) -> str:
    quoted = [f"'{n}'" for n in names]
    return quoted[0] if len(quoted) == 1 else ", ".join(quoted[:-1]) + " and " + quoted[-1]


async def read_parts(request: Request, caps: dict[str, int], required: tuple[str, ...], usage: str) -> dict[str, _Part]:
    """The parts named in ``caps`` (name -> max bytes) of a multipart body, read as a stream
    (413 as soon as a part or the body passes its cap, 422 if malformed, a part is missing
    from ``required``, given twice or unknown). ``usage`` says what the body must be."""
    ctype = request.headers.get("content-type", "")
    kind, params = parse_options_header(ctype)
    if kind != b"multipart/form-data" or b"boundary" not in params:
        raise Unprocessable(usage, loc=["header", "content-type"])
    body_cap = sum(caps.values()) + MULTIPART_OVERHEAD_BYTES
    limits = ", ".join(f"{name} <= {cap}" for name, cap in caps.items())
    declared = request.headers.get("content-length")
    if declared is not None and declared.isdigit() and int(declared) > body_cap:
        raise UploadTooLarge(
            f"request body of {int(declared)} bytes exceeds the upload cap of {body_cap} bytes ({limits})",
            loc=["body", required[0] if required else next(iter(caps))],
        )
    parts: dict[str, _Part] = {}
    state: dict = {"part": None, "hname": bytearray(), "hvalue": bytearray(), "error": None}

    def on_part_begin() -> None:
        state["part"] = _Part()

    def on_header_field(data: bytes, start: int, end: int) -> None:
        state["hname"] += data[start:end]

    def on_header_value(data: bytes, start: int, end: int) -> None:
        state["hvalue"] += data[start:end]

    def on_header_end() -> None:
        part: _Part = state["part"]
        part.headers[bytes(state["hname"]).decode("latin-1").lower()] = bytes(state["hvalue"]).decode("latin-1")
        state["hname"], state["hvalue"] = bytearray(), bytearray()

    def on_headers_finished() -> None:
        part: _Part = state["part"]
        _, opts = parse_options_header(part.headers.get("content-disposition", ""))
        part.name = opts.get(b"name", b"").decode("utf-8", "replace") or None
        fn = opts.get(b"filename")
        part.filename = fn.decode("utf-8", "replace") if fn is not None else None

    def on_part_data(data: bytes, start: int, end: int) -> None:
        part: _Part = state["part"]
        if part.name not in caps:
            return  # unknown part: ignored (reported below), never buffered
        part.data += data[start:end]
        if len(part.data) > caps[part.name] and state["error"] is None:
            state["error"] = UploadTooLarge(
                f"part '{part.name}' exceeds its cap of {caps[part.name]} bytes", loc=["body", part.name]
            )

    def on_part_end() -> None:
        part: _Part = state["part"]
        if part.name is not None:
            if part.name in parts:
                state["error"] = state["error"] or Unprocessable(
                    f"part '{part.name}' given twice", loc=["body", part.name]
                )
            parts[part.name] = part

    callbacks = {
        "on_part_begin": on_part_begin,
        "on_header_field": on_header_field,
        "on_header_value": on_header_value,
        "on_header_end": on_header_end,
        "on_headers_finished": on_headers_finished,
        "on_part_data": on_part_data,
        "on_part_end": on_part_end,
    }
    try:  # python-multipart refuses e.g. a boundary over 256 characters (RFC 2046 allows 70)
        parser = MultipartParser(params[b"boundary"], callbacks)
    except Exception as exc:
        raise Unprocessable(f"malformed multipart header: {exc}", loc=["header", "content-type"]) from exc
    received = 0
    try:
        async for chunk in request.stream():
            received += len(chunk)
            if received > body_cap:
                raise UploadTooLarge(f"request body exceeds the upload cap of {body_cap} bytes ({limits})",
                                     loc=["body", required[0] if required else next(iter(caps))])
            try:
                parser.write(chunk)
            except Exception as exc:  # python-multipart raises its own MultipartParseError
                raise Unprocessable(f"malformed multipart body: {exc}", loc=["body"]) from exc
            if state["error"] is not None:
                raise state["error"]
        try:
            parser.finalize()
        except Exception as exc:
            raise Unprocessable(f"malformed multipart body: {exc}", loc=["body"]) from exc
    except ClientDisconnect as exc:
        raise Unprocessable("client disconnected during the upload", loc=["body"]) from exc
    if state["error"] is not None:
        raise state["error"]
    unknown = sorted(set(parts) - set(caps))
    if unknown:
        raise Unprocessable(
            f"unexpected part(s) {unknown}: only {_listing(caps)} are accepted", loc=["body", unknown[0]]
        )
    for name in required:
        if name not in parts:
            raise Unprocessable(f"missing part '{name}'", loc=["body", name])
    return parts


async def read_upload(request: Request, max_mesh_bytes: int, max_manifest_bytes: int) -> UploadParts:
    """Read ``mesh`` and ``manifest`` parts, or one ``archive`` part (a zip of anatomy files and a build
    manifest, at most ``max_mesh_bytes``), from a multipart body (413 beyond the caps, 422 if malformed)."""
    usage = ("the upload must be multipart/form-data with two parts, 'mesh' (.glb) and 'manifest' (JSON), or one "
             "part 'archive' (a zip of anatomy files and a build manifest)")
    parts = await read_parts(
        request, {"mesh": max_mesh_bytes, "manifest": max_manifest_bytes, "archive": max_mesh_bytes}, (), usage)
    if "archive" in parts:
        extra = sorted(set(parts) - {"archive"})
        if extra:
            raise Unprocessable(f"part '{extra[0]}' comes with 'archive': send either 'archive' alone or 'mesh' and "
                                "'manifest'", loc=["body", extra[0]])
        return UploadParts(archive=bytes(parts["archive"].data))
    for name in ("mesh", "manifest"):
        if name not in parts:
            raise Unprocessable(f"missing part '{name}' ({usage})", loc=["body", name])
    mesh = parts["mesh"]
    if bytes(mesh.data[:4]) != GLB_MAGIC:
        raise InvalidMesh(
            "the mesh is not a binary glTF (.glb): it does not start with the magic bytes 'glTF'",
            loc=["body", "mesh"],
        )
    return UploadParts(bytes(mesh.data), mesh.filename, bytes(parts["manifest"].data))
