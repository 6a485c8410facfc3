"""``sparsesplat fetch-weights``: a valid features-only VGG file is accepted without a
network, and every failure says precisely what failed (issue #11)."""

from __future__ import annotations

import hashlib
import socket
from pathlib import Path

import pytest
import torch

from sparsesplat.client.fetch_weights import (
    MANIFEST,
    VGG16_FEATURES,
    FetchError,
    WeightFile,
    fetch_one,
)
from tests.cli.conftest import run_cli
from tests.conftest import SHARED_MODELS

VGG = "vgg16_features_imagenet_torchvision.pth"


def _dead_url() -> str:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return f"http://127.0.0.1:{s.getsockname()[1]}"


def test_manifest_shapes_are_what_the_lpips_loader_builds() -> None:
    from sparsesplat.engine.metrics.lpips import _vgg_features

    want = {f"features.{k}": tuple(v.shape) for k, v in _vgg_features().state_dict().items()}
    assert want == VGG16_FEATURES


@pytest.mark.skipif(not (SHARED_MODELS / VGG).is_file(), reason="../shared/models absent")
def test_features_only_vgg_is_present_without_network(tmp_path: Path) -> None:
    models = tmp_path / "models"
    models.mkdir()
    (models / VGG).symlink_to(SHARED_MODELS / VGG)
    result = run_cli(
        "fetch-weights", "--models-dir", str(models), "--only", VGG, "--base-url", _dead_url()
    )
    assert result.returncode == 0, result.stderr
    assert "present" in result.stdout and "features-only VGG16" in result.stdout
    # ... and the engine's LPIPS really loads that file.
    from sparsesplat.engine.metrics.lpips import LPIPS

    (models / "lpips_v0.1_lin_vgg.pth").symlink_to(SHARED_MODELS / "lpips_v0.1_lin_vgg.pth")
    LPIPS(models_dir=models)


def test_an_unrecognised_file_is_described_precisely(tmp_path: Path) -> None:
    item = WeightFile("w.pth", "unused", "0" * 64, "test", tensors=dict(VGG16_FEATURES))
    models = tmp_path / "models"
    models.mkdir()
    # Right names, one wrong shape: the loader would refuse it, and the message says which.
    state = {k: torch.zeros(shape) for k, shape in VGG16_FEATURES.items()}
    state["features.0.weight"] = torch.zeros(64, 3, 5, 5)
    torch.save(state, models / "w.pth")
    with pytest.raises(FetchError) as info:
        fetch_one(item, models, base_url=_dead_url(), timeout=2)
    text = str(info.value)
    assert "exists but its sha256" in text and "none of the accepted files" in text
    assert "features.0.weight has shape (64, 3, 5, 5), expected (64, 3, 3, 3)" in text
    assert "No network?" in text and "ConnectError" in text
    assert (models / "w.pth").is_file(), "the existing file is left alone"


def test_a_known_equivalent_is_present(tmp_path: Path) -> None:
    payload = b"features only"
    digest = hashlib.sha256(payload).hexdigest()
    item = WeightFile("w.pth", "unused", "0" * 8, "test", ((digest, "a conversion"),))
    (tmp_path / "w.pth").write_bytes(payload)
    assert fetch_one(item, tmp_path, base_url=_dead_url(), timeout=2) == "present"
    assert {w.name for w in MANIFEST} >= {VGG, "lpips_v0.1_lin_vgg.pth"}
