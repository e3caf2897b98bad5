"""Running the API's request bodies in this process, without HTTP (the CLI's commands): the phantom
registry and limits a server would have (``Settings()`` from the environment), and a refusal written as
the API's error JSON (``{"detail": [{loc, msg, type}]}``)."""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Any, Callable


def local_registry():
    """The built-in (and stored uploaded) phantoms and the settings, as ``(registry, settings)``."""
    from service.registry import Registry
    from service.settings import Settings
    from service.storage import PhantomStore

    settings = Settings()
    registry = Registry(store=PhantomStore(settings.data_dir))
    registry.load_builtins(settings.load_builtins)
    return registry, settings


def error_json(exc: Exception) -> dict[str, Any]:
    """A refusal (service, tracer or estimator error) as the body of the API's 4xx."""
    from raytrace.errors import CapsuleRTError
    from service.errors import ServiceError, field_to_loc

    if isinstance(exc, ServiceError):
        return {"detail": [{"loc": exc.loc, "msg": exc.reason, "type": exc.type}]}
    if isinstance(exc, CapsuleRTError) or hasattr(exc, "field"):
        return {"detail": [{"loc": ["body", *field_to_loc(getattr(exc, "field", None))],
                            "msg": getattr(exc, "reason", str(exc)), "type": type(exc).__name__}]}
    return {"detail": [{"loc": [], "msg": str(exc), "type": type(exc).__name__}]}


def run_file_request(path: str, run: Callable[[Any], Any], refusals: tuple[type[Exception], ...]) -> Any | None:
    """``run`` on the JSON body in the file at ``path``. A file that cannot be read or parsed, a
    ValidationError or one of ``refusals`` is printed to stderr as the API's error JSON and gives
    None (the command then exits 2)."""
    from pydantic import ValidationError

    try:
        payload = json.loads(Path(path).read_text())
    except (OSError, json.JSONDecodeError) as exc:
        print(json.dumps({"detail": [{"loc": ["file"], "msg": str(exc), "type": "invalid_file"}]}), file=sys.stderr)
        return None
    try:
        return run(payload)
    except ValidationError as exc:
        items = [{"loc": ["body", *e["loc"]], "msg": e["msg"], "type": e["type"]} for e in exc.errors()]
        print(json.dumps({"detail": items}, indent=2), file=sys.stderr)
    except refusals as exc:
        print(json.dumps(error_json(exc), indent=2), file=sys.stderr)
    return None
