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


@dataclass(frozen=True)
class WeightFile:
    """One file the models directory should hold."""

    name: str
    """File name in the models directory (what the engine looks up)."""
    url: str
    """Official download location."""
    sha256: str
    """Expected sha256: the full hex digest, or a hex prefix where only that is published
    (torchvision publishes the first 8 hex digits in its file names and checks just those)."""
    purpose: str
    """What needs it."""


MANIFEST: tuple[WeightFile, ...] = (
    WeightFile(
        "vgg16_features_imagenet_torchvision.pth",
        "https://download.pytorch.org/models/vgg16-397923af.pth",
        "397923af",
        "LPIPS (VGG backbone, the paper's metric)",
    ),
    WeightFile(
        "lpips_v0.1_lin_vgg.pth",
        "https://raw.githubusercontent.com/richzhang/PerceptualSimilarity/master/lpips/weights/v0.1/vgg.pth",
        "a78928a0af1e5f0fcb1f3b9e8f8c3a2a5a3de244d830ad5c1feddc79b8432868",
        "LPIPS v0.1 linear heads (VGG)",
    ),
    WeightFile(
        "alexnet_features_imagenet_torchvision.pth",
        "https://download.pytorch.org/models/alexnet-owt-7be5be79.pth",
        "7be5be79",
        "LPIPS (AlexNet backbone)",
    ),
    WeightFile(
        "lpips_v0.1_lin_alex.pth",
        "https://raw.githubusercontent.com/richzhang/PerceptualSimilarity/master/lpips/weights/v0.1/alex.pth",
        "df73285e35b22355a2df87cdb6b70b343713b667eddbda73e1977e0c860835c0",
        "LPIPS v0.1 linear heads (AlexNet)",
    ),
)


class FetchError(Exception):
    """A weights file could not be fetched or failed its checksum."""


def _sha256(path: Path) -> str:
    digest = hashlib.sha256()
    with path.open("rb") as fh:
        for chunk in iter(lambda: fh.read(1 << 20), b""):
            digest.update(chunk)
    return digest.hexdigest()


def _matches(path: Path, expected: str) -> bool:
    return _sha256(path).startswith(expected.lower())


def fetch_one(
    item: WeightFile, models_dir: Path, base_url: str | None = None, timeout: float = 60.0
) -> str:
    """Ensure ``item`` is in ``models_dir`` with the right checksum; return what was done."""
    target = models_dir / item.name
    if target.is_file() and _matches(target, item.sha256):
        return "present"
    url = f"{base_url.rstrip('/')}/{item.name}" if base_url else item.url
    models_dir.mkdir(parents=True, exist_ok=True)
    fd, tmp_name = tempfile.mkstemp(dir=models_dir, prefix=f".{item.name}.", suffix=".part")
    tmp = Path(tmp_name)
    try:
        with (
            os.fdopen(fd, "wb") as out,
            httpx.stream("GET", url, timeout=timeout, follow_redirects=True) as response,
        ):
            if response.status_code != 200:
                raise FetchError(f"{item.name}: {url} answered HTTP {response.status_code}")
            for chunk in response.iter_bytes():
                out.write(chunk)
        got = _sha256(tmp)
        if not got.startswith(item.sha256.lower()):
            raise FetchError(
                f"{item.name}: checksum mismatch for {url}: "
                f"expected sha256 {item.sha256}…, got {got}"
            )
        tmp.replace(target)
        return "downloaded"
    except httpx.TransportError as exc:
        raise FetchError(
            f"{item.name}: cannot download {url} ({exc.__class__.__name__}: {exc}). No network? "
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
            print(f"{outcome:>10}  {models_dir / item.name}  ({item.purpose})")
        except FetchError as exc:
            failures += 1
            print(f"error: {exc}", file=sys.stderr)
    return 1 if failures else 0
