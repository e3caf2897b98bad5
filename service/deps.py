"""Access to the per-app state from route handlers."""

from __future__ import annotations

from dataclasses import dataclass

from fastapi import Request

from service.compute import ComputeGate
from service.metrics import Metrics
from service.registry import Registry
from service.settings import Settings


@dataclass
class AppState:
    settings: Settings
    registry: Registry
    gate: ComputeGate
    metrics: Metrics


def state(request: Request) -> AppState:
    return request.app.state.capsule
