"""Bounded before work: the one rule every write operation and every job kind goes through.

docs/service.md, "Bounded before work", states the rule for users and for whoever adds an
operation or a job kind; this module is the rule:

1. **Declared.** Every write operation (POST, PUT, PATCH, DELETE) carries a :class:`Declaration`,
   put on its route function with :func:`declare`: the cap on its body (bytes, a Settings field or
   a function of the settings), the function that estimates its cost from the request, and whether
   it writes state the API keys guard (uploads, jobs, their deletes). :class:`Gate`, a middleware,
   applies the first and the last before a byte of the body is read: the key (401), then the body's
   size while it streams in (413). A write operation without a declaration gets the strictest one
   (the small JSON cap, keyed) and ``tests/service/test_admission.py`` fails naming it.
2. **Estimated, then admitted.** Before any work the operation (or the job kind, in its submission)
   turns the request into a :class:`Cost`: each work product against its cap (:class:`Work`: ray
   segments, samples, cell updates, particle steps, pixels) and the memory it will hold, by the field
   that makes it grow, against one computation's share (``max_compute_memory_bytes /
   max_concurrency``). :func:`admit` refuses what does not fit with a 422 whose ``loc`` names the
   dominant field and whose message says the estimate, the limit and what to lower. The refusal is
   deterministic, so it is a 422, not a 503 inviting a retry.
3. **Checked while it runs.** Estimates are envelopes; the work itself runs under a
   :class:`~raytrace.solver.budget.Budget` (deadline, work, bytes, cancellation) checked in its loops.

A job kind (:class:`service.jobs.JobKind`) implements ``estimate`` and queues through
:meth:`service.jobs.JobKind.create`, which admits the cost, records the writer's key and stores the
job atomically: a kind without ``estimate`` cannot be registered.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from typing import Any, Callable, Iterable

from starlette.exceptions import HTTPException
from starlette.responses import JSONResponse

from service.errors import Unprocessable, error_body
from service.limits import CEILINGS
from service.settings import Settings

WRITES = frozenset({"POST", "PUT", "PATCH", "DELETE"})

Loc = tuple[str | int, ...]


# ----------------------------------------------------------------------------------- request knobs
def lower_or_refuse(value: int | None, setting: str, settings: Settings, loc: Loc, *, default: int) -> int:
    """The one rule for a request knob that a setting of :data:`service.limits.CEILINGS` caps: a value
    given above this server's limit is a 422 naming ``loc`` (never silently lowered); an absent one
    takes ``default`` lowered to the limit (the served schema's default says the same:
    :meth:`service.limits.Limits.lower_schema`)."""
    if setting not in CEILINGS:
        raise ValueError(f"{setting!r} is not a limit setting")
    cap = int(getattr(settings, setting))
    if value is None:
        return min(default, cap)
    if value > cap:
        raise Unprocessable(f"{value} exceeds this server's limit of {cap}", loc=["body", *loc])
    return value


def trace_knobs(rays: int | None, max_interactions: int | None, settings: Settings, *, default_rays: int,
                default_interactions: int) -> tuple[int, int]:
    """The rays and interactions of an evaluation's traces (:func:`lower_or_refuse` on each)."""
    return (lower_or_refuse(rays, "max_rays", settings, ("rays",), default=default_rays),
            lower_or_refuse(max_interactions, "max_interactions", settings, ("max_interactions",),
                            default=default_interactions))


# ------------------------------------------------------------------------------------------- cost
@dataclass(frozen=True)
class Work:
    """One work product of a request: ``amount`` of ``unit`` against ``cap`` (the Settings field
    ``setting``); ``loc`` is the field (under ``body``) to lower, ``what`` names the work in the
    message and ``advice`` says what else lowers it."""

    loc: Loc
    amount: float
    cap: float
    unit: str
    setting: str
    what: str
    advice: str = ""


@dataclass(frozen=True)
class Cost:
    """What a request will cost, estimated from its fields before any work: its work products and
    its memory as ``(field, bytes)`` terms (the field whose term grows with it)."""

    work: tuple[Work, ...] = ()
    memory: tuple[tuple[Loc, float], ...] = ()
    what: str = "the request"
    knobs: str = ""

    @property
    def memory_bytes(self) -> float:
        return float(sum(b for _, b in self.memory))

    def __add__(self, other: "Cost") -> "Cost":
        knobs = ", ".join(k for k in (self.knobs, other.knobs) if k)
        return Cost(self.work + other.work, self.memory + other.memory, self.what, knobs)


def _text(loc: Loc) -> str:
    out = ""
    for part in loc:
        out += f"[{part}]" if isinstance(part, int) else (f".{part}" if out else str(part))
    return out


def admit(cost: Cost, settings: Settings, *, memory_cap_bytes: float | None = None, where: str = "body") -> None:
    """Refuse ``cost`` (422 naming the dominant field) when a work product exceeds its cap or the
    memory exceeds one computation's share (``memory_cap_bytes`` when given). Work is judged first
    (the product furthest over its cap, as a ratio, is named), then memory (the field of its largest
    term): work that cannot finish is refused whatever memory it would hold."""
    knobs = f" ({cost.knobs})" if cost.knobs else ""
    over = [w for w in cost.work if w.amount > w.cap]
    if over:
        w = max(over, key=lambda w: w.amount / w.cap)
        advice = f": {w.advice}" if w.advice else f": lower {_text(w.loc)}"
        raise Unprocessable(
            f"{w.what} is estimated at {w.amount:.4g} {w.unit}{knobs}, over this server's work budget of "
            f"{w.cap:.4g} ({w.setting}){advice}", loc=[where, *w.loc])
    cap = settings.compute_memory_share_bytes if memory_cap_bytes is None else memory_cap_bytes
    total = cost.memory_bytes
    if cost.memory and total > cap:
        loc = max(cost.memory, key=lambda term: term[1])[0]
        others = ", ".join(dict.fromkeys(_text(term[0]) for term in cost.memory if term[0] != loc))
        raise Unprocessable(
            f"{cost.what} is estimated to need {total / 2**20:.0f} MiB{knobs}, over this server's "
            f"{cap / 2**20:.0f} MiB per computation (max_compute_memory_bytes / max_concurrency); lower "
            f"{_text(loc)} first (its term is the largest)" + (f", or {others}" if others else ""),
            loc=[where, *loc])


# ------------------------------------------------------------------------------------ declarations
BodyCap = Callable[[Settings], int]


@dataclass(frozen=True)
class Declaration:
    """A write operation's bound: its body cap, its cost estimate, whether the API keys guard it."""

    body: BodyCap
    cost: str
    keyed: bool = False


#: What an undeclared write operation gets: the small JSON cap, and the key.
STRICTEST = Declaration(body=lambda s: s.max_json_body_bytes, cost="undeclared", keyed=True)


def declare(*, body: str | BodyCap | None, cost: Callable | str, keyed: bool = False) -> Callable:
    """Mark a route function with its :class:`Declaration` (apply it under the router's decorator).

    ``body``: the Settings field capping the body [bytes] (``max_json_body_bytes`` for request-shaped
    JSON bodies, ``max_ranging_body_bytes`` for data: profiles, plots, observations), a function of the
    settings, or None for an operation that takes no body (a DELETE: the small JSON cap applies).
    ``cost``: the function that turns the request into a :class:`Cost` (or a sentence saying why
    the schema alone bounds it, e.g. a closed form). ``keyed``: the operation writes state (an
    upload, a job, a delete): with API keys configured it needs one (401 before the body is read)."""
    if isinstance(body, str):
        name = body
        if name not in Settings.model_fields:
            raise ValueError(f"no setting {name!r}")
        cap: BodyCap = lambda s: getattr(s, name)  # noqa: E731
    elif body is None:
        cap = STRICTEST.body
    else:
        cap = body
    text = cost if isinstance(cost, str) else f"{cost.__module__}.{cost.__qualname__}"

    def mark(fn: Callable) -> Callable:
        setattr(fn, "__capsule_declaration__", Declaration(cap, text, keyed))
        return fn

    return mark


def declaration_of(endpoint: Callable | None) -> Declaration | None:
    return getattr(endpoint, "__capsule_declaration__", None)


@dataclass
class Table:
    """(method, path pattern) -> declaration of every write operation of the app's routes."""

    rows: list[tuple[re.Pattern, frozenset[str], str, Declaration | None, str]] = field(default_factory=list)

    @classmethod
    def of(cls, routes: Iterable[Any]) -> "Table":
        """The table of ``routes`` (an app's ``router.routes``; included routers are walked into)."""
        table = cls()
        for route in _flatten(routes):
            methods = frozenset(getattr(route, "methods", None) or ()) & WRITES
            if methods:
                table.rows.append((route.path_regex, methods, getattr(route, "operation_id", None) or route.name,
                                   declaration_of(getattr(route, "endpoint", None)), route.path))
        return table

    def find(self, method: str, path: str) -> Declaration | None:
        """The declaration of the write route serving (method, path): its own, or :data:`STRICTEST` for a route
        without one; None when no route serves it (the router answers 404 or 405 and reads no body)."""
        for pattern, methods, _, declared, _ in self.rows:
            if method in methods and pattern.match(path):
                return declared or STRICTEST
        return None

    def undeclared(self) -> list[str]:
        return [name for _, _, name, declared, _ in self.rows if declared is None]

    def keyed(self) -> list[tuple[str, str]]:
        """(path template, method) of every operation the API keys guard."""
        return [(path, m) for _, methods, _, d, path in self.rows if (d or STRICTEST).keyed for m in sorted(methods)]


def _flatten(routes: Iterable[Any]) -> Iterable[Any]:
    """Every route, included routers' too (FastAPI keeps an included router as one entry whose
    ``original_router`` holds its routes, paths prefixed already by their own router's prefix)."""
    for route in routes:
        inner = getattr(route, "original_router", None)
        if inner is not None:
            yield from _flatten(inner.routes)
        else:
            yield route


# ------------------------------------------------------------------------------------- middleware
class Gate:
    """Pure-ASGI middleware applying a write's declaration before its body is read: with API keys
    configured, a keyed operation without a valid key is refused (401); a declared
    ``Content-Length`` over the body cap is refused (413) before anything is read, and a body that
    passes the cap while arriving stops being read there (413). Reads pass untouched."""

    def __init__(self, app, table: Callable[[], Table], settings: Settings) -> None:
        self.app = app
        self._table = table
        self.settings = settings

    async def __call__(self, scope, receive, send):
        if scope["type"] != "http" or scope.get("method") not in WRITES:
            await self.app(scope, receive, send)
            return
        declared = self._table().find(scope["method"], scope.get("path", ""))
        if declared is None:  # no route: the router's 404 / 405, nothing read
            await self.app(scope, receive, send)
            return
        if declared.keyed and self.settings.api_keys:
            from service.security import key_error

            headers = {k.decode("latin-1").lower(): v.decode("latin-1") for k, v in scope.get("headers", [])}
            error = key_error(headers.get("x-api-key"), self.settings)
            if error is not None:
                await JSONResponse(error_body(error.loc, error.reason, error.type), status_code=error.status_code,
                                   headers=error.headers)(scope, receive, send)
                return
        cap = declared.body(self.settings)
        length = next((v for k, v in scope.get("headers", []) if k == b"content-length"), b"")
        if length.isdigit() and int(length) > cap:
            await JSONResponse(error_body(["body"], _too_large_text(cap, int(length)), "too_large"),
                               status_code=413)(scope, receive, send)
            return
        received = 0

        async def receive_capped():
            nonlocal received
            message = await receive()
            if message["type"] == "http.request":
                received += len(message.get("body", b""))
                if received > cap:
                    # an HTTPException reaches the app's handler (JSON body), wherever the read happens
                    raise HTTPException(413, _too_large_text(cap, None))
            return message

        await self.app(scope, receive_capped, send)


def _too_large_text(cap: int, declared: int | None) -> str:
    size = f"of {declared} bytes " if declared is not None else ""
    return f"request body {size}exceeds this operation's cap of {cap} bytes (refused while reading it)"
