"""Shared pieces of every figure: the input base models, a headless figure, bytes out.

Figures are built with matplotlib's object API on an Agg canvas (never pyplot):
no display, no global figure manager, and each call owns its figure, so the
service can render in worker threads. Drawing is serialised by one lock
(matplotlib's text layout and font cache are not documented as thread-safe;
building artists measures no text, drawing does); a figure takes 0.1-0.5 s
and every input is bounded, so the wait is bounded too.
"""

from __future__ import annotations

import io
import re
import threading
from typing import Annotated, Any

from matplotlib import rc_context
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from pydantic import BaseModel, BeforeValidator, ConfigDict, Field, model_validator

#: Output formats: name -> media type.
FORMATS = {"png": "image/png", "svg": "image/svg+xml", "pdf": "application/pdf"}

#: Largest image side [px] (width_in or height_in times dpi).
MAX_SIDE_PX = 3000

#: Colours of the groups of a figure (matplotlib's tab10, colour-blind friendlier than the default cycle).
PALETTE = ["#1f77b4", "#ff7f0e", "#2ca02c", "#d62728", "#9467bd", "#8c564b", "#e377c2", "#7f7f7f",
           "#bcbd22", "#17becf"]

_RENDER_LOCK = threading.Lock()


class PlotInputError(ValueError):
    """Data a figure cannot be drawn from; ``field`` is its dotted path in the input
    (``profile.paths[3].band_gains``), ``reason`` says why."""

    def __init__(self, reason: str, field: str) -> None:
        super().__init__(f"{field}: {reason}")
        self.reason = reason
        self.field = field

    @property
    def loc(self) -> list[str | int]:
        """The field as a path: ``profile.paths[3].band_gains`` -> ``["profile", "paths", 3, "band_gains"]``."""
        parts = re.sub(r"\[(\d+)\]", r".\1", self.field).split(".")
        return [int(p) if p.isdigit() else p for p in parts if p]


class Data(BaseModel):
    """Nested input data (a channel profile, a path...): the fields a figure reads; other
    fields of the API's JSON (segments, gain_db...) are accepted and ignored, so a
    response object can be passed as is."""

    model_config = ConfigDict(extra="ignore", allow_inf_nan=False)


def _integral(value: Any) -> Any:
    """JSON Schema's ``integer`` is any number without a fractional part: ``150.0`` counts as 150
    (the service validates bodies strictly, so without this a float would be refused)."""
    return int(value) if type(value) is float and value.is_integer() else value


#: An integer field of a plot body.
Int = Annotated[int, BeforeValidator(_integral)]


class PlotRequest(BaseModel):
    """Options every figure takes (the top level of a plot body forbids unknown fields)."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    title: str | None = Field(None, max_length=200, description="Figure title (default: one naming the data).")
    width_in: float = Field(8.0, ge=2.0, le=20.0, description="Figure width [in].")
    height_in: float = Field(4.5, ge=2.0, le=20.0, description="Figure height [in].")
    dpi: Int = Field(150, ge=50, le=300, description="Resolution of PNG output [dots per inch].")

    @model_validator(mode="after")
    def _size(self) -> "PlotRequest":
        side = max(self.width_in, self.height_in or 0.0) * self.dpi
        if side > MAX_SIDE_PX:
            raise ValueError(f"the image would be {side:.0f} px wide or high (max {MAX_SIDE_PX}): lower dpi or size")
        return self

    def figure_kwargs(self) -> dict[str, Any]:
        """The figure function's keyword arguments: every field but ``dpi`` (an output option),
        nested data passed as the validated objects (not re-dumped)."""
        return {name: getattr(self, name) for name in type(self).model_fields if name != "dpi"}


def new_figure(width_in: float, height_in: float) -> Figure:
    """A figure on its own Agg canvas, laid out by the constrained layout engine."""
    fig = Figure(figsize=(width_in, height_in), layout="constrained")
    FigureCanvasAgg(fig)
    return fig


def figure_bytes(fig: Figure, fmt: str = "png", dpi: int = 150) -> bytes:
    """Encode a figure as ``png`` / ``svg`` / ``pdf`` (deterministic: no timestamps in svg/pdf metadata)."""
    if fmt not in FORMATS:
        raise PlotInputError(f"unknown format {fmt!r}; one of {', '.join(FORMATS)}", "format")
    metadata = {"png": {"Software": None}, "svg": {"Date": None}, "pdf": {"CreationDate": None}}[fmt]
    buf = io.BytesIO()
    # a fixed salt makes the SVG's element ids (random by default) the same for the same figure
    with _RENDER_LOCK, rc_context({"svg.hashsalt": "capsule-rt"}):
        fig.savefig(buf, format=fmt, dpi=dpi, metadata=metadata)
    return buf.getvalue()
