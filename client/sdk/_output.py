"""Writing what the service answers: files written atomically, frames of a camera path,
metrics as a DataFrame, a model's cameras."""

from __future__ import annotations

import zipfile
from io import BytesIO
from pathlib import Path
from typing import TYPE_CHECKING

from sparsesplat.api.cameras import PinholeCamera
from sparsesplat.api.jobs import ModelInfo, Record
from sparsesplat.api.names import IMAGE_OUTPUT_SUFFIXES
from sparsesplat.api.renders import RenderOutput
from sparsesplat.client import media
from sparsesplat.client.errors import InvalidInput

if TYPE_CHECKING:
    import pandas as pd


_SUFFIX_OUTPUT: dict[str, RenderOutput] = {**IMAGE_OUTPUT_SUFFIXES, ".npy": "npy"}


def unzip_frames(data: bytes) -> list[bytes]:
    with zipfile.ZipFile(BytesIO(data)) as archive:
        return [archive.read(name) for name in sorted(archive.namelist())]


def output_for(path: Path, output: RenderOutput | None) -> RenderOutput:
    if output is not None:
        return output
    try:
        return _SUFFIX_OUTPUT[path.suffix.lower()]
    except KeyError:
        raise InvalidInput(
            f"{path}: cannot tell the output from the suffix; use .png, .jpg, .webp or .npy, "
            "or pass output="
        ) from None


def write_file(path: str | Path, data: bytes) -> Path:
    """Write ``data`` to ``path`` atomically (a partial file never has the final name)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.part")
    tmp.write_bytes(data)
    tmp.replace(path)
    return path


def write_frames(folder: str | Path, frames: list[bytes], output: RenderOutput) -> list[Path]:
    suffix = {"jpeg": "jpg", "depth16": "png", "alpha": "png"}.get(output, output)
    return [write_file(Path(folder) / f"{i:04d}.{suffix}", f) for i, f in enumerate(frames)]


def records_frame(records: list[Record]) -> pd.DataFrame:
    pandas = media.require("pandas", "metrics as a DataFrame")
    frame: pd.DataFrame = pandas.DataFrame(
        [r.model_dump() for r in records], columns=list(Record.model_fields)
    )
    return frame


def model_cameras(info: ModelInfo, split: str | None) -> list[PinholeCamera]:
    out = []
    for frame in info.cameras:
        if split is not None and frame.get("split", "train") != split:
            continue
        out.append(
            PinholeCamera.model_validate(
                {k: frame[k] for k in PinholeCamera.model_fields if k in frame}
            )
        )
    return out
