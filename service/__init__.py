"""CapsuleRT HTTP service: FastAPI app, typed client, CLI."""

__version__ = "0.1.0"
