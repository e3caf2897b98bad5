"""``capsule-rt``: serve the API, run a channel request locally, a demo, or write openapi.json.

    capsule-rt serve [--host H] [--port P] [--workers N] [--data-dir DIR]
    capsule-rt channel REQUEST.json [--output OUT.json] [--export OUT.npz | OUT.csv]
    capsule-rt demo [--rays N]          (default: the API's own default, 100000)
    capsule-rt openapi [--output openapi.json] [--check]
    capsule-rt plot KIND INPUT.json --output OUT.png|svg|pdf [--receiver NAME]
    capsule-rt sweep SPEC --out DIR [--cluster ADDRESS] [--resume]   (service.sweep_cli)
    capsule-rt experiment NAME --out DIR                             (service.sweep_cli)
    capsule-rt design coverage|layout|plot ...                       (service.design_cli)
    capsule-rt fullwave REQUEST.json --out DIR [--cell-mm 2] [--coarse-factor 1.5] [--margin-mm 20] [--reuse]
    capsule-rt vision render --out DIR [--start-s-m S] [--frames N] [--advance-m D] ...   (service.vision_cli)
    capsule-rt vision motion DIR|FRAME.png... [--output OUT.csv|.json] [--estimate both] ... (service.vision_cli)
    capsule-rt localize REQUEST.json [--output OUT.json]            (service.localize_cli)
    capsule-rt localize-evaluate REQUEST.json [--output OUT.json]   (service.localize_cli)
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path
from typing import Any, Sequence

from service.local import error_json, local_registry, run_file_request

REPO_ROOT = Path(__file__).resolve().parent.parent


def openapi_text() -> str:
    """The app's OpenAPI document as stable JSON text (sorted keys, 2-space indent, final newline)."""
    from service.app import create_app
    from service.settings import Settings

    app = create_app(Settings(load_builtins=False))
    return json.dumps(app.openapi(), indent=2, sort_keys=True, ensure_ascii=False) + "\n"


def _cmd_openapi(args: argparse.Namespace) -> int:
    text = openapi_text()
    out = Path(args.output)
    if args.check:
        current = out.read_text() if out.exists() else ""
        if current != text:
            print(f"{out} is out of date; run `capsule-rt openapi`", file=sys.stderr)
            return 1
        print(f"{out} is up to date")
        return 0
    tmp = out.with_suffix(out.suffix + ".tmp")
    tmp.write_text(text)
    os.replace(tmp, out)
    print(f"wrote {out} ({len(text)} bytes)")
    return 0


def _cmd_serve(args: argparse.Namespace) -> int:
    import uvicorn

    from service.settings import Settings

    if args.data_dir:
        os.environ["CAPSULE_RT_DATA_DIR"] = str(args.data_dir)
    settings = Settings()
    host = args.host or settings.host
    port = args.port or settings.port
    workers = args.workers or settings.workers
    # the app (built by uvicorn in each worker from the environment) knows where it is served: its own
    # origin, which browsers' writes must come from (service.security.configured_origins)
    os.environ["CAPSULE_RT_HOST"], os.environ["CAPSULE_RT_PORT"] = host, str(port)
    uvicorn.run(
        "service.app:app",
        host=host,
        port=port,
        workers=workers,
        log_level=settings.log_level,
        access_log=False,  # the app logs one JSON line per request itself
        proxy_headers=True,
        timeout_graceful_shutdown=10,
    )
    return 0


def run_channel_request(payload: dict) -> dict[str, Any]:
    """Run one POST /v1/channel body locally (no HTTP); returns the response dict."""
    from raytrace import Budget, trace_channel
    from service.operations import channel as ops
    from service.schemas.channel import ChannelRequest, ChannelResponse

    registry, settings = local_registry()
    req = ChannelRequest.model_validate(payload)
    spec, phantom = ops.to_spec(req, registry, settings)
    budget = Budget(deadline_s=settings.request_deadline_s, max_ray_segments=settings.max_ray_segments)
    result = trace_channel(spec, phantom, budget=budget, config=settings.tracer_config())
    out = ops.result_to_dict(result, req.scenario, req.outputs)
    return json.loads(ChannelResponse.model_validate(out).model_dump_json())


def _cmd_channel(args: argparse.Namespace) -> int:
    from raytrace.errors import CapsuleRTError
    from service.errors import ServiceError

    out = run_file_request(args.file, run_channel_request, (CapsuleRTError, ServiceError, ValueError))
    if out is None:
        return 2
    text = json.dumps(out, indent=2) + "\n"
    if args.output:
        Path(args.output).write_text(text)
    elif not args.export:
        sys.stdout.write(text)
    if args.export:
        try:
            export_outputs(out, Path(args.export))
        except (OSError, ValueError) as exc:
            print(json.dumps({"detail": [{"loc": ["export"], "msg": str(exc), "type": "export_failed"}]}),
                  file=sys.stderr)
            return 2
    return 0


def export_outputs(response: dict[str, Any], path: Path) -> None:
    """Write a channel response's per-receiver ``cfr`` / ``cir`` / ``taps`` to ``path``: ``.npz``
    (numpy: ``<receiver>/cfr_frequency_hz``, ``<receiver>/cfr`` complex, ``<receiver>/cir_time_s``,
    ``<receiver>/cir``, ``<receiver>/taps_l``, ``<receiver>/taps_delay_s``, ``<receiver>/taps``) or
    ``.csv`` (one row per value: ``receiver,output,index,frequency_hz,delay_s,re,im``; ``delay_s`` is
    the time of a cir sample or the delay of a tap, absolute unless the request normalised delays)."""
    import csv

    import numpy as np

    arrays: dict[str, np.ndarray] = {}
    rows: list[tuple] = []
    for prof in response["profiles"]:
        name = prof["receiver"]
        if prof.get("cfr"):
            c = prof["cfr"]
            h = np.asarray(c["re"]) + 1j * np.asarray(c["im"])
            arrays[f"{name}/cfr_frequency_hz"], arrays[f"{name}/cfr"] = np.asarray(c["frequency_hz"]), h
            rows += [(name, "cfr", i, f, "", z.real, z.imag) for i, (f, z) in enumerate(zip(c["frequency_hz"], h))]
        if prof.get("cir"):
            c = prof["cir"]
            h = np.asarray(c["re"]) + 1j * np.asarray(c["im"])
            arrays[f"{name}/cir_time_s"], arrays[f"{name}/cir"] = np.asarray(c["time_s"]), h
            rows += [(name, "cir", i, "", t, z.real, z.imag) for i, (t, z) in enumerate(zip(c["time_s"], h))]
        if prof.get("taps"):
            c = prof["taps"]
            h = np.asarray(c["re"]) + 1j * np.asarray(c["im"])
            arrays[f"{name}/taps_l"], arrays[f"{name}/taps_delay_s"] = np.asarray(c["l"]), np.asarray(c["delay_s"])
            arrays[f"{name}/taps"] = h
            rows += [(name, "taps", ell, "", d, z.real, z.imag) for ell, d, z in zip(c["l"], c["delay_s"], h)]
    if not arrays:
        raise ValueError("the response holds no channel outputs: add \"outputs\" (cfr, cir, taps) and a band "
                         "to the request")
    suffix = path.suffix.lower()
    if suffix == ".npz":
        np.savez(path, **arrays)
    elif suffix == ".csv":
        with path.open("w", newline="") as fh:
            w = csv.writer(fh)
            w.writerow(["receiver", "output", "index", "frequency_hz", "delay_s", "re", "im"])
            w.writerows((r[0], r[1], r[2], r[3] if r[3] == "" else repr(float(r[3])),
                         r[4] if r[4] == "" else repr(float(r[4])), repr(float(r[5])), repr(float(r[6])))
                        for r in rows)
    else:
        raise ValueError(f"unknown export format {path.suffix!r}: use .npz or .csv")
def _cmd_fullwave(args: argparse.Namespace) -> int:
    """Export a channel request to gprMax, run it at two cell sizes and compare with the tracer
    (fullwave.run; docs/validation.md)."""
    import raytrace as rt
    from fullwave.model import FdtdOptions
    from fullwave.run import compare, gprmax_available
    from raytrace.errors import CapsuleRTError

    try:
        payload = json.loads(Path(args.file).read_text())
        scenario = payload.pop("scenario", None)
        base = rt.get_scenario(scenario).spec if scenario else None
        spec = rt.ChannelSpec.from_dict(payload, base)
        phantom = rt.get_phantom(spec.phantom)
        options = FdtdOptions(cell_m=args.cell_mm * 1e-3, margin_m=args.margin_mm * 1e-3, pml_cells=args.pml_cells)
    except (OSError, json.JSONDecodeError, CapsuleRTError, ValueError) as exc:
        detail = error_json(exc) if isinstance(exc, CapsuleRTError) else {"detail": str(exc)}
        print(json.dumps(detail), file=sys.stderr)
        return 2
    run = not args.export_only
    if run and not gprmax_available():
        print("gprMax is not installed (pip install 'capsule-rt[fullwave]'); writing the inputs only", file=sys.stderr)
        run = False
    report = compare(spec, phantom, options, Path(args.out), coarse_factor=args.coarse_factor or None, run=run,
                     threads=args.threads, reuse=args.reuse)
    for r in report["runs"]:
        if r.get("ran"):
            how = "re-used from an earlier run in --out" if r.get("reused") else "ran"
            print(f"{r['cell_m'] * 1e3:g} mm cells: gprMax {r['wall_s']:.0f} s ({how})", file=sys.stderr)
    sys.stdout.write((Path(args.out) / "report.md").read_text())
    return 0


def _table(rows: Sequence[Sequence[Any]], header: Sequence[str]) -> str:
    cells = [[str(c) for c in header]] + [[str(c) for c in r] for r in rows]
    widths = [max(len(r[i]) for r in cells) for i in range(len(header))]
    line = "  ".join("-" * w for w in widths)
    out = ["  ".join(c.rjust(w) for c, w in zip(cells[0], widths)), line]
    out += ["  ".join(c.rjust(w) for c, w in zip(r, widths)) for r in cells[1:]]
    return "\n".join(out)


_KIND = {"reflection": "R", "refraction": "T", "total_internal_reflection": "TIR"}


def _demo_case(title: str, payload: dict) -> None:
    from service.operations import ranging
    from service.schemas.ranging import PdoaRequest, ToaRequest
    from service.settings import Settings

    print(f"\n=== {title} ===")
    out = run_channel_request(payload)
    stats = out["stats"]
    print(f"phantom {out['phantom']}, {out['frequency_hz'] / 1e6:g} MHz, transmitter in {out['transmitter']['medium']} "
          f"at {[round(x, 4) for x in out['transmitter']['position_m']]} m; "
          f"{stats['rays_launched']} rays, {stats['paths_found']} paths, {stats['elapsed_s']:.2f} s")
    settings = Settings()
    for prof in out["profiles"]:
        print(f"\nreceiver {prof['receiver']} ({prof['medium']}), "
              f"geometric distance {prof['geometric_distance_m'] * 1e3:.2f} mm, "
              f"path gain {prof['path_gain_db']:.1f} dB, rms delay spread {prof['rms_delay_spread_s'] * 1e12:.1f} ps")
        rows = []
        for k, p in enumerate(prof["paths"]):
            kinds = "-".join(_KIND[i["kind"]] for i in p["interactions"]) or "direct"
            rows.append((k, f"{p['delay_s'] * 1e9:.4f}", f"{p['gain_db']:.1f}", f"{p['length_m'] * 1e3:.2f}", kinds))
        if rows:
            print(_table(rows, ["path", "delay [ns]", "gain [dB]", "length [mm]", "interactions (R/T/TIR)"]))
        else:
            print("  (no path found)")
            continue
        truth = prof["geometric_distance_m"]
        toa = ranging.toa(ToaRequest(profile=prof, method="all", trials=50, seed=1, true_distance_m=truth), settings)
        band = {"start_hz": 400e6, "stop_hz": 420e6, "points": 21}
        try:
            pdoa = ranging.pdoa(PdoaRequest(profile=prof, method="regression", band=band, trials=50, seed=1,
                                            true_distance_m=truth), settings)
            results = toa["results"] + pdoa["results"]
        except Exception as exc:  # noqa: BLE001 - show what worked
            print(f"  PDOA unavailable: {exc}")
            results = toa["results"]
        rows = [
            (r["method"], f"{r['distance_m'] * 1e3:.2f}", f"{(r['error_m'] or 0) * 1e3:+.2f}",
             f"{r['std_m'] * 1e3:.3f}", "-" if r["crlb_m"] is None else f"{r['crlb_m'] * 1e3:.4f}")
            for r in results
        ]
        print(_table(rows, ["method", "distance [mm]", "error [mm]", "std [mm]", "CRLB [mm]"]))


def _cmd_demo(args: argparse.Namespace) -> int:
    registry, _ = local_registry()
    cases = []
    # without --rays the requests carry none: the API's (and the scenarios') own default, what a
    # user of the API gets (a sparser launch can miss a sensor's strongest path)
    rays = {} if args.rays is None else {"rays": args.rays}
    if "thesis-fig-5-6" in registry.scenarios:
        cases.append(("thesis-fig-5-6 (thesis Fig 5.5/5.6)", {"scenario": "thesis-fig-5-6", **rays}))
    if "torso-small-intestine" in registry.scenarios:
        cases.append(("default torso, capsule in the small intestine (scenario torso-small-intestine)",
                      {"scenario": "torso-small-intestine", **rays}))
    elif "torso" in registry.builtins:
        torso = registry.builtins["torso"]
        capsule = next((n for n, s in torso.sites.items() if s.kind == "capsule"), None)
        sensors = [n for n, s in torso.sites.items() if s.kind == "sensor"][:4]
        if capsule and sensors:
            cases.append((
                f"default torso, capsule at {capsule}",
                {"phantom": "torso", "transmitter": {"site": capsule}, "receivers": [{"site": n} for n in sensors],
                 "max_interactions": 4, **rays},
            ))
    if not cases:
        print("no built-in scenario or phantom available", file=sys.stderr)
        return 1
    for title, payload in cases:
        _demo_case(title, payload)
    return 0


#: Commands whose parsers import the plotting or the sweep packages (matplotlib, the tracer) to list
#: their choices. When another command runs, or ``capsule-rt --help``, they are listed by name and
#: help only, so that ``--help`` loads neither numba nor matplotlib (tests/service/test_light_imports.py).
DEFERRED = ("plot", "experiment")


def build_parser(command: str | None = None) -> argparse.ArgumentParser:
    """The ``capsule-rt`` parser; ``command``: the one about to run (the :data:`DEFERRED` parsers are
    built in full only for themselves); None builds every parser in full."""
    p = argparse.ArgumentParser(prog="capsule-rt", description="CapsuleRT in-body channel emulator.")
    sub = p.add_subparsers(dest="command", required=True, metavar="COMMAND", help="what to do")
    s = sub.add_parser("serve", help="run the HTTP API (uvicorn)")
    s.add_argument("--host", default=None, help="bind address (default CAPSULE_RT_HOST or 127.0.0.1)")
    s.add_argument("--port", type=int, default=None, help="port (default CAPSULE_RT_PORT or 8000)")
    s.add_argument("--workers", type=int, default=None, help="worker processes (default CAPSULE_RT_WORKERS or 1)")
    s.add_argument("--data-dir", default=None, help="upload directory (default CAPSULE_RT_DATA_DIR or ./data)")
    s.set_defaults(func=_cmd_serve)
    c = sub.add_parser("channel", help="run a POST /v1/channel body locally and print the response JSON")
    c.add_argument("file", help="JSON file with the request body")
    c.add_argument("--output", "-o", default=None, help="write the response here instead of stdout")
    c.add_argument("--export", default=None, help="also write the request's channel outputs (cfr / cir / taps) "
                   "to this .npz or .csv file")
    c.set_defaults(func=_cmd_channel)
    d = sub.add_parser("demo", help="trace thesis-fig-5-6 and a default-torso case; print paths and TOA/PDOA")
    d.add_argument("--rays", type=int, default=None,
                   help="rays launched per trace (default: the API's default, 100000; fewer is faster but "
                   "may miss weak or grazing paths)")
    d.set_defaults(func=_cmd_demo)
    o = sub.add_parser("openapi", help="write openapi.json (stable key order)")
    o.add_argument("--output", "-o", default=str(REPO_ROOT / "openapi.json"),
                   help="where to write it (default: openapi.json at the repository root)")
    o.add_argument("--check", action="store_true", help="exit 1 if the file differs instead of writing it")
    o.set_defaults(func=_cmd_openapi)
    if command is None or command == "plot":
        from plots import cli as plots_cli

        plots_cli.add_parser(sub)
    else:
        sub.add_parser("plot", help="draw a figure from a JSON file (the kinds: capsule-rt plot --help)")
    from service import sweep_cli

    sweep_cli.add_parsers(sub, experiment=command is None or command == "experiment")
    f = sub.add_parser("fullwave", help="export a channel request to gprMax, run it and compare with the tracer")
    f.add_argument("file", help="JSON file with a POST /v1/channel body (ChannelSpec)")
    f.add_argument("--out", required=True, help="directory for the gprMax inputs, outputs and report.{json,md}")
    f.add_argument("--cell-mm", type=float, default=2.0, help="FDTD cell edge [mm] (default 2)")
    f.add_argument("--coarse-factor", type=float, default=1.5,
                   help="second run's cells are this much larger, for the discretisation estimate (0: no second run)")
    f.add_argument("--margin-mm", type=float, default=20.0, help="margin around the antennas' box [mm] (default 20)")
    f.add_argument("--pml-cells", type=int, default=10, help="absorbing-layer thickness [cells] (default 10)")
    f.add_argument("--threads", type=int, default=2, help="OpenMP threads for gprMax (default 2)")
    f.add_argument("--export-only", action="store_true", help="write the gprMax inputs, do not run them")
    f.add_argument("--reuse", action="store_true",
                   help="a cell size whose identical input already ran to the end in --out is not run again (its "
                        "output is compared anew): rebuild a report, or finish an interrupted comparison")
    f.set_defaults(func=_cmd_fullwave)
    from service import localize_cli, phantom_cli, track_cli, vision_cli

    phantom_cli.add_parsers(sub)
    vision_cli.add_parsers(sub)
    localize_cli.add_parsers(sub)
    track_cli.add_parser(sub)
    from service import design_cli

    design_cli.add_parser(sub)
    return p


def main(argv: Sequence[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    command = next((a for a in argv if not a.startswith("-")), "")
    args = build_parser(None if command in DEFERRED else command).parse_args(argv)
    return int(args.func(args) or 0)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
