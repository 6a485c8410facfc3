"""The rasterizer's portable tile kernels built for aarch64 and run under qemu-user.

Torch does not run under emulation here at a usable cost, so the kernels are driven by a small
torch-free program (``native_arm/driver.cpp``) cross-compiled with Debian's
``aarch64-linux-gnu-g++`` from the same sources and aarch64 baseline flags as the extension
(:func:`engine.native_build.baseline_cflags`). :class:`EmulatedRaster` stands in for the native
extension's module: the x86 build still sorts and bins the Gaussians (plain C++ shared by every
architecture), and every tile's forward and backward blending runs in the emulated aarch64
binary. Patched into ``cpu_backend``, it lets the float64-reference comparisons of the x86 tests
run unchanged on the aarch64 kernels.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import tempfile
from pathlib import Path
from types import ModuleType

import numpy as np
import torch
from torch import Tensor

from sparsesplat.engine.native_build import baseline_cflags
from sparsesplat.engine.raster.build import SOURCE_DIR

CXX = "aarch64-linux-gnu-g++"
"""Debian's cross compiler for aarch64 (package g++-aarch64-linux-gnu)."""
QEMU = "qemu-aarch64"
"""User-mode emulator (package qemu-user)."""
DRIVER_SOURCE = Path(__file__).resolve().parent / "native_arm" / "driver.cpp"
"""The torch-free driver of the tile kernels."""
MAGIC = 0x53525344
"""First header value of a driver input file (driver.cpp's kMagic)."""
HEADER_INTS = 16
"""Length of the int32 header (driver.cpp's kHeaderInts)."""
FORWARD, BACKWARD, RECIPROCAL = 0, 1, 2
"""Driver modes."""
HAS_DEPTH_OPACITY, GEOMETRY = 1, 2
"""Header flags."""
GRAD_FIXED = 7
"""Gradient slots per Gaussian before the channels (common.h's kGradFixed)."""
REC_FLOATS = 16
"""Floats per packed record (common.h's GaussRec, one cache line)."""


def missing_tools() -> list[str]:
    """The cross compiler and emulator that are not on PATH."""
    return [tool for tool in (CXX, QEMU) if shutil.which(tool) is None]


def driver_command(output: Path) -> list[str]:
    """The cross-compile command of the driver: the extension's aarch64 baseline flags (OpenMP
    aside: the kernels have none), statically linked so qemu needs no aarch64 libraries."""
    flags = [f for f in baseline_cflags("aarch64") if f != "-fopenmp"]
    return [
        CXX, *flags, "-static", "-I", str(SOURCE_DIR), str(DRIVER_SOURCE),
        str(SOURCE_DIR / "kernels_portable.cpp"), "-o", str(output),
    ]  # fmt: skip


def build_driver(output: Path) -> Path:
    """Cross-compile the driver to ``output``; the compiler's output on failure."""
    done = subprocess.run(driver_command(output), capture_output=True, text=True)
    assert done.returncode == 0, f"aarch64 build failed:\n{done.stderr[-4000:]}"
    return output


def run_driver(driver: Path, header: list[int], arrays: list[np.ndarray]) -> bytes:
    """Run the driver under qemu on one input (header + arrays); returns its output's bytes."""
    head = np.zeros(HEADER_INTS, np.int32)
    head[: len(header)] = header
    with tempfile.TemporaryDirectory(prefix="arm64-driver-") as tmp:
        src, dst = Path(tmp) / "in.bin", Path(tmp) / "out.bin"
        with open(src, "wb") as f:
            f.write(head.tobytes())
            for a in arrays:
                f.write(np.ascontiguousarray(a).tobytes())
        done = subprocess.run([QEMU, str(driver), str(src), str(dst)], capture_output=True,
                              text=True, timeout=300)  # fmt: skip
        assert done.returncode == 0, f"driver failed ({done.returncode}): {done.stderr[-2000:]}"
        return dst.read_bytes()


def _np(t: Tensor) -> np.ndarray:
    return t.detach().contiguous().numpy()


class _Outputs:
    """Consecutive arrays of a driver output."""

    def __init__(self, data: bytes) -> None:
        self.data, self.at = data, 0

    def take(self, dtype: type, shape: tuple[int, ...]) -> Tensor:
        n = int(np.prod(shape))
        a = np.frombuffer(self.data, dtype, n, self.at).reshape(shape)
        self.at += a.nbytes
        return torch.from_numpy(a.copy())


class EmulatedRaster:
    """The native rasterizer module's ``forward`` / ``backward`` / ``variant``, with every tile
    blended by the aarch64 driver under qemu (see the module docstring)."""

    def __init__(self, native: ModuleType, driver: Path) -> None:
        self.native = native
        self.driver = driver
        self.runs = 0
        """Driver runs so far (tests check the emulation did run)."""

    def _run(self, header: list[int], arrays: list[np.ndarray]) -> bytes:
        self.runs += 1
        return run_driver(self.driver, header, arrays)

    def variant(self) -> str:
        """What runs the tiles."""
        return "portable (aarch64 under qemu)"

    def forward(self, means2d: Tensor, conics: Tensor, opacities: Tensor, depths: Tensor,
                radii: Tensor, features: Tensor, bg: Tensor, width: int, height: int,
                keep_state: bool) -> list[Tensor]:  # fmt: skip
        """As raster.cpp's forward: the x86 build sorts and bins, the driver blends."""
        state = self.native.forward(means2d, conics, opacities, depths, radii, features, bg,
                                    width, height, True)[4:9]  # fmt: skip
        recs, feats, rank, offsets, lists = state
        c, m = features.shape[1], feats.shape[0]
        header = [MAGIC, FORWARD, width, height, c, m, lists.numel(), 0, 0]
        arrays = [_np(recs), _np(feats), _np(lists), _np(offsets), _np(bg)]
        out = _Outputs(self._run(header, arrays))
        image = out.take(np.float32, (c, height, width))
        depth = out.take(np.float32, (1, height, width))
        alpha = out.take(np.float32, (1, height, width))
        t_final = out.take(np.float32, (height, width))
        last = out.take(np.int32, (height, width))
        stats = out.take(np.int64, (2,))
        result = [image, depth, alpha, stats]
        if keep_state:
            result += [recs, feats, rank, offsets, lists, t_final, last]
        return result

    def backward(self, recs: Tensor, feats: Tensor, rank: Tensor, offsets: Tensor,
                 lists: Tensor, t_final: Tensor, last: Tensor, bg: Tensor, v_image: Tensor,
                 v_depth: Tensor, v_alpha: Tensor, v_depth_opacity: Tensor | None, n: int,
                 geometry: bool) -> list[Tensor]:  # fmt: skip
        """As raster.cpp's backward: the driver's per-record sums, scattered to the Gaussians."""
        c, m = feats.shape[1], feats.shape[0]
        height, width = t_final.shape
        flags = (GEOMETRY if geometry else 0) | (HAS_DEPTH_OPACITY if v_depth_opacity is not None
                                                 else 0)  # fmt: skip
        header = [MAGIC, BACKWARD, width, height, c, m, lists.numel(), flags, 0]
        arrays = [_np(recs), _np(feats), _np(lists), _np(offsets), _np(bg), _np(t_final),
                  _np(last), _np(v_image), _np(v_depth), _np(v_alpha)]  # fmt: skip
        if v_depth_opacity is not None:
            arrays.append(_np(v_depth_opacity))
        grads = _Outputs(self._run(header, arrays)).take(np.float32, (m, c + GRAD_FIXED))
        ids = rank.long()

        def scatter(cols: slice, shape: tuple[int, ...]) -> Tensor:
            full = torch.zeros(shape, dtype=torch.float32)
            full[ids] = grads[:, cols].reshape(m, *shape[1:])
            return full

        return [
            scatter(slice(0, 2), (n, 2)),
            scatter(slice(2, 5), (n, 3)),
            scatter(slice(5, 6), (n,)),
            scatter(slice(6, 7), (n,)),
            scatter(slice(GRAD_FIXED, GRAD_FIXED + c), (n, c)),
        ]

    def reciprocal(self, x: np.ndarray, estimate: np.ndarray) -> np.ndarray:
        """The kernels' 1/x from the estimate, by the emulated aarch64 kernels."""
        header = [MAGIC, RECIPROCAL, 0, 0, 0, 0, 0, 0, x.size]
        data = self._run(header, [x.astype(np.float32), estimate.astype(np.float32)])
        return np.frombuffer(data, np.float32).copy()


def driver_path() -> Path:
    """Where the session's driver is built: a fresh temporary folder (removed at exit by the
    fixture that calls this)."""
    return Path(tempfile.mkdtemp(prefix="arm64-driver-")) / f"driver-{os.getpid()}"
