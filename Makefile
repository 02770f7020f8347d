# The front door.  `make demo` and `make test` do everything on a fresh
# Debian bookworm machine (as root, or with sudo): install what is missing,
# build, run.

PYTHON  ?= /usr/bin/python3
BLENDER ?= blender
BLENDER_RUN = $(BLENDER) -b --factory-startup --python-exit-code 1
DEBIAN_PACKAGES = blender libosd-dev libembree-dev cmake g++ make python3-numpy python3-scipy python3-pytest \
                  python3-matplotlib libsuitesparse-dev
SUDO := $(shell [ "$$(id -u)" = 0 ] || echo sudo)

.PHONY: all deps build test test-c test-asan test-python test-blender demo bench bench-scale bench-closest clean

all: build

# Installs only the packages that are missing (apt-get update once, first).
deps:
	@missing=$$(for p in $(DEBIAN_PACKAGES); do dpkg -s $$p >/dev/null 2>&1 || echo $$p; done); \
	if [ -n "$$missing" ]; then \
	  echo "installing:" $$missing; \
	  $(SUDO) apt-get update -qq && \
	  DEBIAN_FRONTEND=noninteractive $(SUDO) apt-get install -y -qq $$missing; \
	fi

build: deps
	$(PYTHON) setup.py build

test: build test-c test-asan test-python test-blender

test-c: build
	ctest --test-dir build/cmake --output-on-failure

test-asan: deps
	cmake -S . -B build/asan -DCMAKE_BUILD_TYPE=RelWithDebInfo -DSPIA_SANITIZE=ON
	cmake --build build/asan --parallel 2
	ASAN_OPTIONS=detect_leaks=1:abort_on_error=1 UBSAN_OPTIONS=print_stacktrace=1:halt_on_error=1 \
	  ctest --test-dir build/asan --output-on-failure

test-python: build
	SUBDIV_PIA_ADDON_DIR=build/addon $(PYTHON) -m pytest -q tests/python

test-blender: build
	$(BLENDER_RUN) --python tests/blender/run.py

demo: build
	mkdir -p out
	$(BLENDER_RUN) --python build/addon/subdiv_pia/cli.py -- tests/data/mushroom.obj out/mushroom_interpolated.blend
	$(BLENDER_RUN) --python bench/render_comparison.py -- tests/data/mushroom.obj out/mushroom_comparison.png

bench: build bench-scale bench-closest
	$(PYTHON) bench/bench_interpolate.py
	$(PYTHON) bench/bench_loop_papers.py
	$(PYTHON) bench/bench_doosabin.py
	$(BLENDER_RUN) --python bench/bench_fit.py
	$(BLENDER_RUN) --python bench/render_fit.py -- --case bunny --scale 2e-3
	$(BLENDER_RUN) --python bench/render_fit.py -- --case dragon --scale 2e-3

# Speed and scale (bench/bench_scale.py; BENCH_QUICK=1 for a short subset).  The
# OpenSubdiv helper is built in its own tree, with -DSPIA_BENCH=ON.
bench-scale: build
	cmake -S . -B build/bench -DCMAKE_BUILD_TYPE=Release -DSPIA_BENCH=ON -DSPIA_TESTS=OFF
	cmake --build build/bench --target spia_bench_osd --parallel 2
	$(PYTHON) bench/bench_scale.py --blender $(BLENDER)

# Closest points: the library's hierarchy against Embree's point query (the
# system's Embree 4 or 3, linked into the benchmark only; without one the
# hierarchy is measured alone) on the bunny and dragon scans and a synthetic
# one of 4 million triangles.  The table goes to out/bench/closest.md.
bench-closest: deps
	cmake -S . -B build/bench -DCMAKE_BUILD_TYPE=Release -DSPIA_BENCH=ON -DSPIA_TESTS=OFF
	cmake --build build/bench --target spia_bench_closest --parallel 2
	mkdir -p out/bench
	build/bench/bench/spia_bench_closest --out out/bench/closest.md

clean:
	$(PYTHON) setup.py clean
