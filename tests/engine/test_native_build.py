"""The native extensions' build cache is keyed by content, not by checkout or by name alone.

Two checkouts on one machine used to rebuild each other's extensions (torch caches by name
under $TORCH_EXTENSIONS_DIR, and ninja rebuilds when the source paths in its commands change).
"""

from __future__ import annotations

import os
import shutil
from pathlib import Path

import pytest

from sparsesplat.engine import native_build
from sparsesplat.engine.color import build as color_build
from sparsesplat.engine.errors import RasterError
from sparsesplat.engine.native_build import NativeExtension, build_key, stage_sources
from sparsesplat.engine.photometric import build as photometric_build
from sparsesplat.engine.raster import build as raster_build

TOOLCHAIN = {
    "torch": "2.13.0",
    "torch_path": "/venv/lib/python3.11/site-packages/torch",
    "python": "cpython-311",
    "python_include": "/usr/include/python3.11",
    "machine": "x86_64",
    "cxx": "c++",
}


def _tree(root: Path, files: dict[str, str]) -> Path:
    root.mkdir(parents=True)
    for name, text in files.items():
        (root / name).write_text(text)
    return root


FILES = {"a.cpp": "int a() { return 1; }\n", "b.cpp": "int b();\n", "common.h": "#pragma once\n"}


def test_same_sources_same_key_wherever_they_live(tmp_path: Path) -> None:
    """Two checkouts of the same sources (different paths) share one key."""
    one = _tree(tmp_path / "one" / "cpu", FILES)
    two = _tree(tmp_path / "elsewhere" / "deeper" / "cpu", FILES)
    files = native_build.staged_files(one, ["a.cpp", "b.cpp"])
    assert files == ["a.cpp", "b.cpp", "common.h"]
    key = build_key(one, files, ["-O3"], toolchain=TOOLCHAIN)
    assert key == build_key(two, files, ["-O3"], toolchain=TOOLCHAIN)
    assert len(key) == native_build.KEY_LENGTH and int(key, 16) >= 0


@pytest.mark.parametrize(
    "change",
    ["source byte", "header", "new header", "cflags", "ldflags", "torch", "venv", "compiler"],
)
def test_any_change_gives_another_key(tmp_path: Path, change: str) -> None:
    """A changed source, header or flag, another torch or compiler, or another virtual
    environment (its paths are in the build commands) builds afresh."""
    src = _tree(tmp_path / "cpu", FILES)
    cflags, ldflags, toolchain = ["-O3"], ["-fopenmp"], dict(TOOLCHAIN)

    def key() -> str:
        files = native_build.staged_files(src, ["a.cpp", "b.cpp"])
        return build_key(src, files, cflags, ldflags, toolchain)

    before = key()
    if change == "source byte":
        (src / "a.cpp").write_text(FILES["a.cpp"].replace("1", "2"))
    elif change == "header":
        (src / "common.h").write_text("#pragma once\n#define X 1\n")
    elif change == "new header":
        (src / "extra.h").write_text("\n")
    elif change == "cflags":
        cflags.append("-ffp-contract=off")
    elif change == "ldflags":
        ldflags.append("-lm")
    elif change == "torch":
        toolchain["torch"] = "2.14.0"
    elif change == "venv":
        toolchain["torch_path"] = "/elsewhere/.venv/lib/python3.11/site-packages/torch"
    else:
        toolchain["cxx"] = "clang++"
    assert key() != before, change


def test_native_cpu_flags_key_on_the_cpu(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A build for the build machine's CPU (-march=native) is keyed by that CPU too."""
    src = _tree(tmp_path / "cpu", FILES)
    monkeypatch.setattr(native_build, "_cpu_model", lambda: "cpu A")
    a = build_key(src, ["a.cpp"], ["-march=native"], toolchain=TOOLCHAIN)
    portable = build_key(src, ["a.cpp"], ["-mavx2"], toolchain=TOOLCHAIN)
    monkeypatch.setattr(native_build, "_cpu_model", lambda: "cpu B")
    assert build_key(src, ["a.cpp"], ["-march=native"], toolchain=TOOLCHAIN) != a
    assert build_key(src, ["a.cpp"], ["-mavx2"], toolchain=TOOLCHAIN) == portable


def test_staging_leaves_unchanged_files_alone(tmp_path: Path) -> None:
    """Re-staging identical sources keeps their modification times (ninja would rebuild)."""
    src = _tree(tmp_path / "cpu", FILES)
    dest = tmp_path / "build" / "src"
    stage_sources(src, list(FILES), dest)
    old = dest / "a.cpp"
    os.utime(old, (1_000_000, 1_000_000))
    stage_sources(src, list(FILES), dest)
    assert old.stat().st_mtime == 1_000_000
    (src / "b.cpp").write_text("int b() { return 2; }\n")
    stage_sources(src, list(FILES), dest)
    assert (dest / "b.cpp").read_text() == "int b() { return 2; }\n"
    assert sorted(p.name for p in dest.iterdir()) == sorted(FILES)


@pytest.mark.parametrize(
    "ext",
    [
        raster_build._EXTENSION,
        raster_build._PROJECTION,
        color_build._EXTENSION,
        photometric_build._EXTENSION,
    ],
)
def test_a_second_checkout_reuses_the_build(ext: NativeExtension, tmp_path: Path) -> None:
    """A copy of the real sources elsewhere (a second clone) maps to the same build directory,
    and loading it there reuses the compiled module: nothing is rebuilt."""
    built = ext.load()
    library = Path(str(built.__file__))
    mtime = library.stat().st_mtime_ns
    copy = tmp_path / "clone" / "cpu"
    shutil.copytree(ext.source_dir, copy)
    twin = NativeExtension(ext.name, copy, ext.sources, ext.cflags, RasterError, "", "twin")
    assert twin.build_name() == ext.build_name()
    assert library.parent == native_build.extensions_root() / ext.build_name()
    loaded = twin.load()
    assert Path(str(loaded.__file__)) == library
    assert library.stat().st_mtime_ns == mtime, "the second checkout rebuilt the extension"
    # A changed source in the copy is another build (not run here: it would compile).
    with open(copy / ext.sources[0], "a") as f:
        f.write("\n// changed\n")
    assert twin.build_name() != ext.build_name()


def test_a_stale_build_lock_from_a_killed_process_does_not_block_loading(tmp_path: Path) -> None:
    """torch's builder marks a build with a plain ``lock`` file; a process killed meanwhile
    leaves it behind, and every later load used to wait for it forever."""
    ext = raster_build._PROJECTION
    built = ext.load()
    stale = native_build.extensions_root() / ext.build_name() / "lock"
    stale.write_text("")
    copy = tmp_path / "clone" / "cpu"
    shutil.copytree(ext.source_dir, copy)
    fresh = NativeExtension(ext.name, copy, ext.sources, ext.cflags, RasterError, "", "fresh")
    loaded = fresh.load()  # would hang here (the test's timeout) before the fix
    assert Path(str(loaded.__file__)) == Path(str(built.__file__))
    assert not stale.exists()


def test_every_extension_builds_from_the_shared_baseline() -> None:
    """One list of baseline flags (x86-64-v3 + OpenMP); the extensions that must round as
    their torch references add only ``-ffp-contract=off``."""
    exact = {raster_build._PROJECTION, color_build._EXTENSION, photometric_build._EXTENSION}
    for ext in [raster_build._EXTENSION, *exact]:
        extra = (native_build.NO_FP_CONTRACT,) if ext in exact else ()
        assert ext.cflags == (*native_build.BASELINE_CFLAGS, *extra), ext.description


def test_a_failed_build_names_the_requirements_and_the_way_out(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The typed error says what every build needs, then the extension's own hint."""
    from torch.utils import cpp_extension

    def fail(**_: object) -> None:
        raise RuntimeError("g++: command not found")

    monkeypatch.setenv("TORCH_EXTENSIONS_DIR", str(tmp_path / "ext"))
    monkeypatch.setattr(cpp_extension, "load", fail)
    src = _tree(tmp_path / "src", FILES)
    ext = NativeExtension("t", src, ["a.cpp"], ["-O3"], RasterError, "set X=torch", "test ext")
    with pytest.raises(RasterError) as info:
        ext.load()
    assert f"({native_build.REQUIREMENTS}; set X=torch): g++: command not found" in str(info.value)
    bare = NativeExtension("t", src, ["a.cpp"], ["-O3"], RasterError, "", "test ext")
    with pytest.raises(RasterError, match=r"\(needs g\+\+ with AVX2 support and ninja\): g\+\+"):
        bare.load()


def test_baseline_flags_follow_the_cpu_architecture() -> None:
    """x86-64 keeps the x86-64-v3 baseline; aarch64 (macOS says arm64) gets ARMv8-A, which has
    NEON, and no x86 flag; any other machine no instruction-set flag at all."""
    common = ("-fopenmp", "-fno-math-errno", "-std=c++17")
    assert native_build.baseline_cflags("x86_64") == ("-O3", "-mavx2", "-mfma", "-mf16c", *common)
    assert native_build.baseline_cflags("AMD64") == native_build.baseline_cflags("x86_64")
    arm = native_build.baseline_cflags("aarch64")
    assert arm == native_build.baseline_cflags("arm64") == ("-O3", "-march=armv8-a", *common)
    assert native_build.baseline_cflags("riscv64") == ("-O3", *common)
    assert native_build.requirements("aarch64") == "needs g++ and ninja"
    assert native_build.baseline_cflags() == native_build.BASELINE_CFLAGS


def test_an_extension_that_cannot_be_built_warns_once_and_is_not_retried(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture
) -> None:
    """load_or_none: None where the build fails, with one warning naming the extension, the
    CPU, the fallback (what runs instead, how much slower) and the compiler's complaint; the
    build is not tried again in the process."""
    from torch.utils import cpp_extension

    calls = []

    def fail(**_: object) -> None:
        calls.append(1)
        raise RuntimeError("build failed\ng++: error: unrecognized command-line option '-mavx2'")

    monkeypatch.setenv("TORCH_EXTENSIONS_DIR", str(tmp_path / "ext"))
    monkeypatch.setattr(cpp_extension, "load", fail)
    src = _tree(tmp_path / "src", FILES)
    fallback = "the torch implementation runs instead, 10x slower"
    ext = NativeExtension("t", src, ["a.cpp"], ["-O3"], RasterError, "", "test ext", fallback)
    with caplog.at_level("WARNING"):
        assert ext.load_or_none() is None
        assert ext.load_or_none() is None
    warned = [r.getMessage() for r in caplog.records if "could not be built" in r.getMessage()]
    assert len(warned) == 1 and len(calls) == 1, (warned, calls)
    assert "the test ext could not be built on this CPU (" in warned[0]
    assert fallback in warned[0] and "unrecognized command-line option '-mavx2'" in warned[0]


def test_every_extension_says_what_runs_instead_and_how_much_slower() -> None:
    """Each extension's fallback text names its torch stand-in and the slowdown; the
    rasterizer's says the dense reference fits small images only."""
    for ext in (raster_build._EXTENSION, raster_build._PROJECTION, color_build._EXTENSION,
                photometric_build._EXTENSION):  # fmt: skip
        assert "torch" in ext.fallback and "slower" in ext.fallback, ext.description
    assert "small images" in raster_build._EXTENSION.fallback


def test_a_kernel_that_cannot_be_built_reads_as_the_torch_fallback(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """load_kernels (the CLI's and the workers' set-up) does not fail on an extension that
    cannot be built: its variant reads 'torch', the others load as usual."""
    from sparsesplat.engine import kernels

    monkeypatch.setattr(raster_build, "load_projection_extension_or_none", lambda: None)
    variants = kernels.load_kernels(color=False, training=False)
    assert variants["projection"] == kernels.FALLBACK, variants
    assert variants["rasterizer"] != kernels.FALLBACK, variants
