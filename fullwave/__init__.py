"""Full-wave (FDTD, gprMax) cross-checks of the ray tracer: export a channel request to a gprMax
model, run it, and compare per receiver (docs/validation.md)."""

from .model import FdtdModel, FdtdOptions, build_model
from .run import compare, gprmax_available

__all__ = ["FdtdModel", "FdtdOptions", "build_model", "compare", "gprmax_available"]
