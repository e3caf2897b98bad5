"""``capsule-rt phantom build MANIFEST --out DIR``: the anatomy pipeline from the command line
(docs/phantoms.md).

Writes ``DIR/phantom.glb`` and ``DIR/manifest.json`` (together what ``POST /v1/phantoms`` accepts as an
upload) and the build report as ``DIR/report.json`` and ``DIR/report.md``. The files are written into a
temporary directory beside ``DIR`` and moved into place only once all of them are complete, so a failed
build leaves ``DIR`` as it was. Bad input exits with status 2 and one line on stderr naming the manifest
entry (file, organ, label) and the reason.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import sys
import tempfile
import time
from pathlib import Path

OUTPUT_FILES = ("phantom.glb", "manifest.json", "report.json", "report.md")


def write_outputs(result, out: Path) -> None:
    """The phantom's .glb, its upload manifest and the report, all or nothing (module docstring)."""
    from raytrace.body.anatomy import markdown_report
    from raytrace.body.gltf import export_glb, export_manifest

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=".tmp-build-", dir=out))
    try:
        (tmp / "phantom.glb").write_bytes(export_glb(result.phantom))
        manifest = export_manifest(result.phantom)
        (tmp / "manifest.json").write_text(json.dumps(manifest, separators=(",", ":")) + "\n")  # compact: an upload
        (tmp / "report.json").write_text(json.dumps(result.report, indent=1, default=float) + "\n")
        (tmp / "report.md").write_text(markdown_report(result.report))
        for name in OUTPUT_FILES:
            os.replace(tmp / name, out / name)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def _cmd_build(args: argparse.Namespace) -> int:
    from raytrace.body.anatomy import build_phantom, parse_manifest_text
    from raytrace.errors import CapsuleRTError, field_text

    path = Path(args.manifest)
    started = time.monotonic()

    def progress(fraction: float, message: str) -> None:
        if not args.quiet:
            print(f"[{time.monotonic() - started:6.1f} s] {100 * fraction:3.0f} % {message}", file=sys.stderr,
                  flush=True)

    try:
        try:
            text = path.read_bytes()
        except OSError as exc:
            print(f"capsule-rt phantom build: {path}: {exc.strerror or exc}", file=sys.stderr)
            return 2
        root = Path(args.data) if args.data else path.parent
        result = build_phantom(parse_manifest_text(text, filename=path.name), root, progress=progress)
    except CapsuleRTError as exc:
        where = field_text(exc.field)
        print(f"capsule-rt phantom build: {where + ': ' if where else ''}{exc.reason}", file=sys.stderr)
        return 2
    write_outputs(result, Path(args.out))
    report = result.report
    print(f"built {report['name']!r}: {report['triangles']} triangles, {len(report['organs'])} organs, "
          f"{len(report['sites'])} sites -> {args.out}/{{{','.join(OUTPUT_FILES)}}}")
    return 0


def add_parsers(sub) -> None:
    p = sub.add_parser("phantom", help="build a phantom from anatomy files and a manifest (docs/phantoms.md)")
    psub = p.add_subparsers(dest="phantom_command", required=True, metavar="ACTION")
    b = psub.add_parser("build", help="build MANIFEST (YAML or JSON) into DIR: phantom.glb + manifest.json "
                        "(what POST /v1/phantoms accepts) + report.{json,md}")
    b.add_argument("manifest", help="the build manifest; its file names are relative to its directory")
    b.add_argument("--out", required=True, help="output directory")
    b.add_argument("--data", default=None, help="directory the manifest's file names are relative to (default: the "
                   "manifest's own directory)")
    b.add_argument("--quiet", "-q", action="store_true", help="no progress lines on stderr")
    b.set_defaults(func=_cmd_build)
