"""POST /v1/plots/{kind}: figures of the API's data, PNG by default, SVG or PDF on request (Accept).

One route per kind of :data:`plots.registry.KINDS`, its body that kind's input
model (so /docs shows each with an example and a bad field gets the usual 422
naming it). Rendering runs in a worker thread through the compute gate, like
every heavy request; its cost is bounded by the models' caps on point counts
and image size.
"""

from fastapi import APIRouter, Request, Response
from fastapi.responses import JSONResponse

from plots.figure import FORMATS, PlotInputError
from plots.registry import KINDS, PlotKind, render
from raytrace import Budget
from service import costs
from service.admission import admit, declare
from service.bodies import ThreadedJsonRoute
from service.deps import state
from service.errors import ServiceError, Unprocessable, error_body, error_responses
from service.schemas import ErrorResponse

router = APIRouter(prefix="/v1/plots", tags=["plots"], route_class=ThreadedJsonRoute)

_WILDCARDS = {"*/*": "png", "image/*": "png", "application/*": "pdf"}
_BY_MEDIA = {media: fmt for fmt, media in FORMATS.items()}


class NotAcceptable(ServiceError):
    status_code = 406
    type = "not_acceptable"


def negotiate(accept: str | None) -> str:
    """The output format an ``Accept`` header asks for: the highest q among image/png,
    image/svg+xml and application/pdf (an exact type before a wildcard at equal q); png
    when the header is absent or only wildcards match."""
    if not accept or not accept.strip():
        return "png"
    best: tuple[float, int, int, str] | None = None
    for order, part in enumerate(accept.split(",")):
        media, *params = [p.strip() for p in part.split(";")]
        media = media.lower()
        q = 1.0
        for param in params:
            if param.lower().startswith("q="):
                try:
                    q = float(param[2:])
                except ValueError:
                    q = 0.0
        fmt = _BY_MEDIA.get(media)
        exact = fmt is not None
        fmt = fmt or _WILDCARDS.get(media)
        if fmt is None or not q > 0.0:
            continue
        key = (q, int(exact), -order, fmt)
        if best is None or key[:3] > best[:3]:
            best = key
    if best is None:
        raise NotAcceptable(f"Accept {accept[:100]!r} allows none of {', '.join(_BY_MEDIA)}",
                            loc=["header", "accept"])
    return best[3]


_IMAGE_RESPONSES = {
    200: {
        "description": "The figure (`Accept: image/svg+xml` or `application/pdf` for those formats).",
        "content": {media: {"schema": {"type": "string", "format": "binary"}} for media in FORMATS.values()},
    },
    406: {"model": ErrorResponse, "description": "The Accept header allows none of PNG, SVG, PDF."},
    **error_responses(400, 422, 503, 504),
}


def plot_cost(req) -> costs.Cost:
    """A figure's cost (:func:`service.costs.plot`): its canvas at ``dpi`` and one artist per number sent."""
    dpi = getattr(req, "dpi", 150)
    width, height = (getattr(req, "width_in", 8.0) or 8.0) * dpi, (getattr(req, "height_in", None) or 8.0) * dpi
    count, stack = 0, [req.model_dump()]
    while stack:
        value = stack.pop()
        if isinstance(value, dict):
            stack.extend(value.values())
        elif isinstance(value, list):
            stack.extend(value)
        elif isinstance(value, (int, float)):
            count += 1
    return costs.plot(width, height, count)


def _add_route(spec: PlotKind) -> None:
    model = spec.request

    async def plot(req: model, request: Request) -> Response:  # type: ignore[valid-type]
        fmt = negotiate(request.headers.get("accept"))
        st = state(request)

        def work(budget: Budget) -> bytes:
            admit(plot_cost(req), st.settings)
            try:
                return render(spec.name, req, fmt)
            except PlotInputError as exc:
                raise Unprocessable(exc.reason, loc=["body", *exc.loc]) from exc

        image = await st.gate.run(work, Budget(deadline_s=st.settings.request_deadline_s),
                                  disconnected=request.is_disconnected)
        return Response(image, media_type=FORMATS[fmt], headers={"Vary": "Accept"})

    plot.__doc__ = (f"{spec.summary}. The body is the figure's data and options (`title`, `width_in`, "
                    "`height_in`, `dpi`); the answer is the image: PNG unless `Accept` asks for "
                    "`image/svg+xml` or `application/pdf`.")
    declare(body="max_ranging_body_bytes", cost=plot_cost)(plot)
    router.add_api_route(f"/{spec.name}", plot, methods=["POST"], operation_id=f"plot_{spec.name}",
                         summary=spec.summary, response_class=Response, responses=_IMAGE_RESPONSES)


for _spec in KINDS.values():
    _add_route(_spec)


@router.post("/{kind}", include_in_schema=False)
@declare(body="max_json_body_bytes", cost="none: answers 404 without reading the body")
async def unknown_kind(kind: str) -> JSONResponse:
    return JSONResponse(error_body(["path", "kind"], f"unknown plot kind {kind[:64]!r}; one of "
                                   f"{', '.join(KINDS)}", "not_found"), status_code=404)
