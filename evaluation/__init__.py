"""End-to-end evaluations that compose the tracer (``raytrace``) and the estimators:
travel-time fields of a phantom, the eikonal check of the tracer, and the localization
pipeline capsule -> trace -> ranges -> position (docs/localization.md)."""
