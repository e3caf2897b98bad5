"""``capsule-rt localize`` and ``capsule-rt localize-evaluate``: a POST /v1/localize or
/v1/localize/evaluate body run locally, the response JSON printed (docs/localization.md)."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

from service.local import local_registry, run_file_request

__all__ = ["add_parsers", "run_localize_request"]


def run_localize_request(payload: dict, *, evaluate: bool = False) -> dict[str, Any]:
    """Run one POST /v1/localize (or /v1/localize/evaluate) body locally (no HTTP); the response dict."""
    from raytrace import Budget
    from service.operations import localize as op
    from service.schemas import localize as loc

    registry, settings = local_registry()
    model, run, response = ((loc.LocalizeEvaluateRequest, op.evaluate, loc.LocalizeEvaluateResponse) if evaluate
                            else (loc.LocalizeRequest, op.localize, loc.LocalizeResponse))
    req = model.model_validate(payload)
    budget = Budget(deadline_s=settings.request_deadline_s, max_ray_segments=settings.max_ray_segments)
    return json.loads(response.model_validate(run(req, registry, settings, budget)).model_dump_json())


def _cmd_localize(args: argparse.Namespace) -> int:
    from estimators.errors import EstimatorInputError
    from raytrace.errors import CapsuleRTError
    from service.errors import ServiceError

    evaluate = args.command == "localize-evaluate"
    out = run_file_request(args.file, lambda body: run_localize_request(body, evaluate=evaluate),
                           (CapsuleRTError, ServiceError, EstimatorInputError))
    if out is None:
        return 2
    text = json.dumps(out, indent=2) + "\n"
    if args.output:
        Path(args.output).write_text(text)
    else:
        sys.stdout.write(text)
    return 0


def add_parsers(sub) -> None:
    lz = sub.add_parser("localize", help="a position fix from a POST /v1/localize body (sensors with ranges, delays "
                        "or received powers); prints the response JSON", description="The capsule's position from "
                        "the sensors of REQUEST.json by the method it names (docs/localization.md); the answer is "
                        "POST /v1/localize's.")
    lz.add_argument("file", help="JSON file with the request body: {\"sensors\": [{\"position_m\" or \"site\", "
                    "\"range_m\" | \"delay_s\" | \"rss_dbm\", \"sigma_m\"?}, ...], \"method\": ...}")
    lz.add_argument("--output", "-o", default=None, help="write the response JSON here instead of stdout")
    lz.set_defaults(func=_cmd_localize)
    le = sub.add_parser("localize-evaluate", help="trace, range and locate a POST /v1/localize/evaluate body; prints "
                        "the per-method error statistics beside the position bound", description="One trace from "
                        "the capsule to the sensors, Monte Carlo ranging, a fix per trial and method "
                        "(docs/localization.md, \"End-to-end evaluation\"); the answer is POST "
                        "/v1/localize/evaluate's.")
    le.add_argument("file", help="JSON file with the request body: {\"capsule\": {\"site\": ...}, \"sensors\": "
                    "[...], \"ranging\": \"gcc\", \"methods\": [...], \"trials\": 20, ...}")
    le.add_argument("--output", "-o", default=None, help="write the response JSON here instead of stdout")
    le.set_defaults(func=_cmd_localize)
