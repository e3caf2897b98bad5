"""The application layer: the work behind each endpoint, one module per concept, shared by the
routes (service.routes), the CLI (service.cli and its commands) and the jobs (docs/architecture.md,
"The service's layers"). No HTTP here: an operation takes a request model, the phantom registry,
the settings and a Budget, and returns the response's dict or raises a typed error (a 4xx)."""
