"""Running the API's request bodies in this process, without HTTP (the CLI's commands): the phantom
registry and limits a server would have (``Settings()`` from the environment), and a refusal written as
the API's error JSON (``{"detail": [{loc, msg, type}]}``)."""

from __future__ import annotations

from typing import Any


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
