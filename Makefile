# Two commands matter: `make run` (service up, embedded defaults) and `make test`.
# Both create the virtual environment on first use.
PYTHON ?= python3
VENV ?= .venv
PY := $(VENV)/bin/python
PIP := $(PY) -m pip --disable-pip-version-check
BENCH_ARGS ?=

.PHONY: run test test-arm64 check-arm64-build lint typecheck dockerlint composelint pytest venv clean bench-raster bench-quality bench-iteration bench-parts bench-reference-depth bench-per-view bench-service bench-render-sheet bench-cameras bench-matchers

venv: $(VENV)/.installed

# torch is installed first and pinned; nothing installed after it may replace it
# (our own build needs only setuptools, so build isolation cannot pull torch either).
$(VENV)/.installed: pyproject.toml
	$(PYTHON) -c 'import sys; assert sys.version_info >= (3, 11), "Python >= 3.11 required"'
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PIP) install -q "torch==2.13.0"
	$(PIP) install -q -e ".[dev]"
	$(PY) -c 'import torch; assert torch.__version__.startswith("2.13.0"), torch.__version__'
	touch $@

# The native CPU kernels are compiled here, during set-up (minutes, once per install or
# update; a cached build only loads), so the first job does not wait for the compiler.
run: venv
	$(VENV)/bin/sparsesplat build
	$(VENV)/bin/sparsesplat serve

lint: venv
	$(PY) -m ruff check .
	$(PY) -m ruff format --check .

typecheck: venv
	$(PY) -m mypy -p sparsesplat.api -p sparsesplat.client -p sparsesplat.server -p sparsesplat.worker -p sparsesplat.engine -p benchmarks

dockerlint: venv
	$(VENV)/bin/hadolint docker/Dockerfile.cpu docker/Dockerfile.cuda

# The compose file against the Compose Specification's JSON schema (check-jsonschema ships it;
# no Docker engine runs here). tests/distributed/test_compose.py checks its commands and
# settings against the real CLI and Settings.
composelint: venv
	$(VENV)/bin/check-jsonschema --builtin-schema vendor.compose-spec docker/compose.yaml

# pytest exits 5 when a selection collects no test: not a failure of the code.
# The native kernels are compiled first, with no time limit: left to the first test that needs
# them, a build on a busy machine outran the service tests' readiness wait (420 s). Without a
# compiler the build fails and the CPU path falls back to torch; the tests that need a kernel
# say so themselves.
pytest: venv
	$(VENV)/bin/sparsesplat build || echo "the native kernels were not built (see above)"
	$(PY) -m pytest; status=$$?; if [ $$status -eq 5 ]; then exit 0; fi; exit $$status

test: lint typecheck dockerlint composelint pytest

# The rasterizer's aarch64 (NEON) kernels against the float64 reference: cross-compiled from the
# same sources and run under qemu-user (Debian: apt-get install g++-aarch64-linux-gnu
# qemu-user). A missing tool fails here; in `make test` those tests skip without them.
test-arm64: venv
	SPARSESPLAT_REQUIRE_ARM64=1 $(PY) -m pytest -q tests/engine/raster/test_arm64_emulated.py

# Every native extension's sources cross-compiled for aarch64 (objects only: no aarch64 torch
# to link against here); needs g++-aarch64-linux-gnu.
check-arm64-build: venv
	$(PY) -m sparsesplat.engine.arm64_build

# The benchmarks live in benchmarks/ at the repository root: run from here, never installed.
bench-raster: venv
	$(PY) -m benchmarks.raster $(BENCH_ARGS)

bench-quality: venv
	$(PY) -m benchmarks.quality $(BENCH_ARGS)

bench-iteration: venv
	$(PY) -m benchmarks.iteration $(BENCH_ARGS)

bench-parts: venv
	$(PY) -m benchmarks.parts $(BENCH_ARGS)

bench-reference-depth: venv
	$(PY) -m benchmarks.reference_depth $(BENCH_ARGS)

bench-per-view: venv
	$(PY) -m benchmarks.per_view $(BENCH_ARGS)

bench-render-sheet: venv
	$(PY) -m benchmarks.render_sheet $(BENCH_ARGS)

bench-cameras: venv
	$(PY) -m benchmarks.cameras $(BENCH_ARGS)

# The learned matchers against the dataset's epipolar geometry, then the matched start.
bench-matchers: venv
	$(PY) -m benchmarks.matchers $(BENCH_ARGS)
	$(PY) -m benchmarks.matched_start

bench-service: venv
	$(PY) -m benchmarks.service $(BENCH_ARGS)

clean:
	rm -rf $(VENV) .cache .mypy_cache .ruff_cache .pytest_cache build dist *.egg-info
