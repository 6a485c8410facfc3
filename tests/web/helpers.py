"""Helpers shared by the web page tests (test_page.py, test_viewer.py)."""

from __future__ import annotations

import io
from dataclasses import dataclass, field
from typing import Any

import httpx
import numpy as np
from PIL import Image

TERMINAL = {"succeeded", "failed", "cancelled"}
PINHOLE_FIELDS = ("convention", "pose", "matrix", "fx", "fy", "cx", "cy", "width", "height")


def pixels(png: bytes) -> np.ndarray:
    """Decoded RGB(A) pixels of an encoded image."""
    with Image.open(io.BytesIO(png)) as image:
        return np.asarray(image.convert("RGBA"))


def post_render(url: str, model_id: str, camera: dict[str, Any]) -> bytes:
    """``POST /v1/models/{id}/render`` for one camera (PNG)."""
    response = httpx.post(
        f"{url}/v1/models/{model_id}/render", json={"camera": camera, "output": "png"}, timeout=120
    )
    assert response.status_code == 200, response.text
    return response.content


def wire_cameras(url: str, model_id: str) -> list[dict[str, Any]]:
    """The model's cameras as PinholeCamera dicts, with their split."""
    model = httpx.get(f"{url}/v1/models/{model_id}", timeout=30).json()
    return [{**{k: c[k] for k in PINHOLE_FIELDS}, "split": c["split"]} for c in model["cameras"]]


def settle(page: Any) -> str:
    """Wait until the viewer has drawn a complete, sorted frame; returns it as a data URL."""
    return str(page.evaluate("() => window.sparsesplat.view.snapshot()"))


@dataclass
class TrainedJob:
    """The module's job, submitted and watched through the page."""

    id: str
    state: str
    seen: list[tuple[str, int]] = field(default_factory=list)
    """(state, chart points) sampled while it trained."""
    chart_points: int = 0
    connections: int = 0
    console_errors: list[str] = field(default_factory=list)
    api_key_in_session: Any = None
    photos: int = 0
    """Uploaded photos the job page shows beside the renders (same tab as the upload)."""


FORM_BUDGET_S = 6.0
"""Training seconds of the job the form submits (a time budget, not a count of iterations:
at a record every second the chart gains about six points whatever the machine's speed; 60
iterations trained in under 2 s on a fast CI machine and left the chart one live point)."""
