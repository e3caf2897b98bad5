"""``capsule-rt plot KIND INPUT.json -o OUT.png|svg|pdf``: a figure from a JSON file, locally.

INPUT is the body of POST /v1/plots/KIND, e.g. ``{"profile": {...}}``. For the
profile kinds (``pdp``, ``cfr``) it may also be a whole POST /v1/channel
response: ``--receiver`` picks the profile by receiver name or index (default
the first). The format follows OUT's suffix. Bad data: the API's error JSON on
stderr (``detail[].loc`` names the field) and exit status 2.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path
from typing import Any

from plots.figure import FORMATS
from plots.registry import KINDS

_PROFILE_KINDS = ("pdp", "cfr")


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("plot", help="draw a figure (" + ", ".join(KINDS) + ") from a JSON file",
                       description=__doc__.split("\n\n", 1)[1], formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("kind", choices=sorted(KINDS), help="; ".join(f"{k}: {v.summary}" for k, v in KINDS.items()))
    p.add_argument("input", help="JSON file: the POST /v1/plots/KIND body (or, for pdp/cfr, a channel response)")
    p.add_argument("--output", "-o", required=True, help="image file; its suffix picks the format (.png, .svg, .pdf)")
    p.add_argument("--receiver", default=None, help="with a channel response: the profile's receiver name or index")
    p.set_defaults(func=run)


def _errors(items: list[dict[str, Any]]) -> int:
    print(json.dumps({"detail": items}, indent=2), file=sys.stderr)
    return 2


def _body(kind: str, data: Any, receiver: str | None) -> dict[str, Any]:
    """The plot body of an input file: itself, or a channel response's profile wrapped as ``{"profile": ...}``."""
    if not (isinstance(data, dict) and "profiles" in data and "profile" not in data):
        return data
    if kind not in _PROFILE_KINDS:
        raise LookupError(f"a channel response can only be drawn as {' or '.join(_PROFILE_KINDS)}")
    profiles = data["profiles"]
    if not isinstance(profiles, list) or not profiles:
        raise LookupError("the channel response has no profiles")
    if receiver is None:
        return {"profile": profiles[0]}
    names = [p.get("receiver") if isinstance(p, dict) else None for p in profiles]
    if receiver in names:
        return {"profile": profiles[names.index(receiver)]}
    if receiver.isdigit() and int(receiver) < len(profiles):
        return {"profile": profiles[int(receiver)]}
    raise LookupError(f"no receiver {receiver!r}; receivers: {', '.join(str(n) for n in names)}")


def run(args: argparse.Namespace) -> int:
    from pydantic import ValidationError

    from plots.figure import PlotInputError
    from plots.registry import render

    out = Path(args.output)
    fmt = out.suffix.lower().lstrip(".")
    if fmt not in FORMATS:
        return _errors([{"loc": ["output"], "msg": f"suffix {out.suffix!r}: use one of "
                         f"{', '.join('.' + f for f in FORMATS)}", "type": "invalid_format"}])
    try:
        data = json.loads(Path(args.input).read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        return _errors([{"loc": ["input"], "msg": str(exc), "type": "invalid_file"}])
    try:
        image = render(args.kind, _body(args.kind, data, args.receiver), fmt)
    except LookupError as exc:
        return _errors([{"loc": ["receiver"], "msg": str(exc.args[0]), "type": "not_found"}])
    except ValidationError as exc:
        return _errors([{"loc": ["body", *e["loc"]], "msg": e["msg"], "type": e["type"]} for e in exc.errors()])
    except PlotInputError as exc:
        return _errors([{"loc": ["body", *exc.loc], "msg": exc.reason, "type": "invalid"}])
    tmp = out.with_name(out.name + ".tmp")
    tmp.write_bytes(image)
    os.replace(tmp, out)
    print(f"wrote {out} ({len(image)} bytes, {args.kind})")
    return 0
