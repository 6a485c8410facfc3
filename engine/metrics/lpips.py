"""LPIPS (v0.1, VGG16 backbone) without torchvision, loading the weights from the models dir.

Input range: DNGaussian evaluates with ``lpipsPyTorch`` (inherited from 3DGS), which feeds
renders and ground truth in [0, 1] straight into the LPIPS scaling layer
((x - shift) / scale, with shift/scale defined for inputs in [-1, 1]) -- it does not rescale
to [-1, 1]. The reference code comments that this "may be a mistake"; we follow it so our
numbers compare with the paper's. ``input_range="minus_one_one"`` gives the original LPIPS
convention (x * 2 - 1 first) for comparisons with the ``lpips`` package.

Per layer (relu1_2, relu2_2, relu3_3, relu4_3, relu5_3): unit-normalise over channels
(eps 1e-10), squared difference, 1x1 linear head (no bias), spatial mean; sum the layers.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from sparsesplat.engine.metrics.image import MetricError, as_hwc
from sparsesplat.engine.weights import resolve_weight

VGG_FILE = "vgg16_features_imagenet_torchvision.pth"
LIN_FILE = "lpips_v0.1_lin_vgg.pth"
SHIFT = (-0.030, -0.088, -0.188)
SCALE = (0.458, 0.448, 0.450)
# torchvision vgg16().features: conv channels, "M" = max-pool. Taps after the ReLU that ends
# each block (torchvision indices 3, 8, 15, 22, 29).
_VGG_CFG = (64, 64, "M", 128, 128, "M", 256, 256, 256, "M", 512, 512, 512, "M", 512, 512, 512)
_TAPS = (3, 8, 15, 22, 29)
_CHANNELS = (64, 128, 256, 512, 512)


def _vgg_features() -> nn.Sequential:
    layers: list[nn.Module] = []
    cin = 3
    for item in _VGG_CFG:
        if item == "M":
            layers.append(nn.MaxPool2d(2, 2))
        else:
            layers += [nn.Conv2d(cin, int(item), 3, padding=1), nn.ReLU(inplace=False)]
            cin = int(item)
    return nn.Sequential(*layers)


class LPIPS(nn.Module):
    """LPIPS-VGG distance; build once and reuse (the network is ~59 MB)."""

    def __init__(self, models_dir: Path | None = None, input_range: str = "zero_one") -> None:
        """Load the VGG16 features and LPIPS v0.1 heads via :func:`resolve_weight`.

        ``input_range``: 'zero_one' (DNGaussian's evaluation, the default) or
        'minus_one_one' (original LPIPS: images are mapped from [0, 1] to [-1, 1])."""
        super().__init__()
        if input_range not in ("zero_one", "minus_one_one"):
            raise MetricError(f"LPIPS input_range must be zero_one|minus_one_one: {input_range!r}")
        self.input_range = input_range
        self.features = _vgg_features()
        state = torch.load(
            resolve_weight(VGG_FILE, models_dir), map_location="cpu", weights_only=True
        )
        # Keep only the conv stack: a full torchvision checkpoint (what `sparsesplat
        # fetch-weights` downloads) also carries the classifier, which LPIPS does not use.
        self.features.load_state_dict(
            {k.removeprefix("features."): v for k, v in state.items() if k.startswith("features.")}
        )
        lin = torch.load(
            resolve_weight(LIN_FILE, models_dir), map_location="cpu", weights_only=True
        )
        self.heads = nn.ParameterList(
            [
                nn.Parameter(lin[f"lin{i}.model.1.weight"].float(), requires_grad=False)
                for i in range(5)
            ]
        )
        for i, c in enumerate(_CHANNELS):
            if self.heads[i].shape != (1, c, 1, 1):
                raise MetricError(f"{LIN_FILE}: head {i} has shape {tuple(self.heads[i].shape)}")
        self.shift: Tensor
        self.scale: Tensor
        self.register_buffer("shift", torch.tensor(SHIFT).view(1, 3, 1, 1))
        self.register_buffer("scale", torch.tensor(SCALE).view(1, 3, 1, 1))
        self.requires_grad_(False)
        self.eval()

    def _taps(self, x: Tensor) -> list[Tensor]:
        out = []
        for i, layer in enumerate(self.features):
            x = layer(x)
            if i in _TAPS:
                out.append(x / (x.pow(2).sum(1, keepdim=True).sqrt() + 1e-10))
                if len(out) == len(_TAPS):
                    break
        return out

    def forward(self, render: Tensor, gt: Tensor) -> Tensor:
        """Distance per batch item for (N, 3, H, W) images in [0, 1]; returns (N,)."""
        if render.shape != gt.shape or render.ndim != 4 or render.shape[1] != 3:
            raise MetricError(
                f"LPIPS needs matching (N, 3, H, W), got {tuple(render.shape)} "
                f"and {tuple(gt.shape)}"
            )
        return self.distance_to_features(render, self.features_of(gt))

    def features_of(self, images: Tensor) -> list[Tensor]:
        """Normalised VGG taps of (N, 3, H, W) images in [0, 1]. A fixed reference image (the
        ground truth of a held-out view) needs them once, not at every evaluation."""
        if self.input_range == "minus_one_one":
            images = images * 2 - 1
        return self._taps((images - self.shift) / self.scale)

    def distance_to_features(self, render: Tensor, reference: list[Tensor]) -> Tensor:
        """Distance per batch item between ``render`` and precomputed reference taps."""
        total = torch.zeros(render.shape[0], dtype=render.dtype, device=render.device)
        for head, a, b in zip(self.heads, self.features_of(render), reference, strict=True):
            total = total + F.conv2d((a - b) ** 2, head).mean(dim=(1, 2, 3))
        return total

    @torch.no_grad()
    def distance(self, render: Any, gt: Any) -> float:
        """LPIPS between two (H, W, 3) images in [0, 1] (tensors or arrays)."""
        a = torch.from_numpy(as_hwc(render, "render")).float().permute(2, 0, 1)[None]
        b = torch.from_numpy(as_hwc(gt, "gt")).float().permute(2, 0, 1)[None]
        return float(self(a.to(self.shift.device), b.to(self.shift.device))[0])


_CACHE: dict[tuple[str, str], LPIPS] = {}


def lpips_distance(render: Any, gt: Any, models_dir: Path | None = None) -> float:
    """LPIPS-VGG (DNGaussian convention) between two HWC images, with a cached network."""
    key = (str(models_dir), "zero_one")
    if key not in _CACHE:
        _CACHE[key] = LPIPS(models_dir)
    return _CACHE[key].distance(render, gt)
