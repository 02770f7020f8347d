# SPDX-License-Identifier: GPL-3.0-or-later
# The front door.  `make demo` and `make test` do everything on a fresh
# Debian 12 (bookworm) or 13 (trixie) machine, as root (or with sudo):
# install what is missing, build, run.

PYTHON  ?= /usr/bin/python3
BLENDER ?= blender
BLENDER_RUN = $(BLENDER) -b --factory-startup --python-exit-code 1
# What building, testing and packaging need, on either release.  The
# Linux package is built in a Debian 11 chroot (debootstrap) from Debian's
# source package of OpenSubdiv (dpkg-source), the Windows one with mingw-w64
# and tested under Wine, the macOS ones with PyPI's Zig; every build links
# OpenSubdiv built from that source package.
DEBIAN_PACKAGES = blender cmake g++ clang make binutils python3-numpy python3-scipy python3-pytest \
                  python3-matplotlib python3-venv libsuitesparse-dev debootstrap dpkg-dev xz-utils \
                  g++-mingw-w64-x86-64 wine wine64 xvfb xauth libgl1-mesa-dri
# Installed where the release has them: the closest-point benchmark compares
# the library with Embree (3 on Debian 12, 4 on 13).
OPTIONAL_PACKAGES = libembree-dev
# Every build links OpenSubdiv 3.6.0's static core, built once under build/osd/host
# from the source package the shipped library is built from (tools/package.py),
# so that each computes what the package computes.
OSD_ARGS = $(shell $(PYTHON) tools/package.py opensubdiv-cmake-args)
SUDO := $(shell [ "$$(id -u)" = 0 ] || echo sudo)
VERSION = $(shell $(PYTHON) tools/package.py version)
# The Linux extension (Blender 4.2 and newer: the add-on and the wheel) and
# the legacy add-ons (Blender 3.4 to 4.1) the Blender and package tests use.
EXTENSION = dist/subdiv_pia-$(VERSION)-linux_x64.zip
LEGACY = dist/subdiv_pia-$(VERSION)-legacy-linux_x64.zip
WINDOWS_LEGACY = dist/subdiv_pia-$(VERSION)-legacy-windows_x64.zip

.PHONY: all deps build package macos test test-c test-asan test-tsan test-fuzz fuzz test-python test-package test-blender test-window \
        blenders demo bench bench-creases bench-scale bench-solve bench-closest bench-live bench-hard bench-fit-scale bench-scan clean

all: build

# Installs only the packages that are missing (apt-get update once, first).
deps:
	@missing=$$(for p in $(DEBIAN_PACKAGES); do dpkg -s $$p >/dev/null 2>&1 || echo $$p; done); \
	optional=$$(for p in $(OPTIONAL_PACKAGES); do dpkg -s $$p >/dev/null 2>&1 || echo $$p; done); \
	if [ -n "$$missing$$optional" ]; then \
	  echo "installing:" $$missing $$optional; \
	  $(SUDO) apt-get update -qq && \
	  DEBIAN_FRONTEND=noninteractive $(SUDO) apt-get install -y -qq $$missing && \
	  for p in $$optional; do \
	    if apt-cache show $$p >/dev/null 2>&1; then \
	      DEBIAN_FRONTEND=noninteractive $(SUDO) apt-get install -y -qq $$p; fi; done; \
	fi

# Development: the library against the machine's OpenSubdiv, the add-on
# around it in build/addon/subdiv_pia.
build: deps
	$(PYTHON) setup.py build

# What is shipped, for Linux x64, Windows x64, macOS arm64 and x86_64
# (tools/package.py): the libraries; a wheel of each (pip: `import spia`)
# and the sdist; an extension of each (Blender 4.2 and newer: the add-on and
# that wheel) and dist/repo/, a static extension repository listing them;
# a legacy add-on of each (Blender 3.4 to 4.1).  The C tests run on each
# library as it is built (the Windows one under Wine); the macOS ones, which
# nothing here can run, are audited instead (tests/package/macho_audit.py).
package: deps
	$(SUDO) $(PYTHON) tools/package.py all

test: build test-c test-asan test-tsan test-fuzz test-python test-package test-blender test-window

# The macOS libraries alone (arm64 and x86_64, macOS 11 and newer), cross-built
# with PyPI's Zig in build/venv-macos and audited with PyPI's LIEF, and what
# is made of them.
macos: deps
	$(PYTHON) tools/package.py macos

# The C tests, and no circle among the library's source files (which file
# calls which, read from the build's objects).
test-c: build
	ctest --test-dir build/cmake --output-on-failure --parallel 2
	$(PYTHON) tools/file_deps.py build/cmake

test-asan: deps
	cmake -S . -B build/asan $(OSD_ARGS) -DCMAKE_BUILD_TYPE=RelWithDebInfo -DSPIA_SANITIZE=ON
	cmake --build build/asan --parallel 2
	ASAN_OPTIONS=detect_leaks=1:abort_on_error=1 UBSAN_OPTIONS=print_stacktrace=1:halt_on_error=1 \
	  ctest --test-dir build/asan --output-on-failure --parallel 2

# ThreadSanitizer: interpolations, fits and closest-point queries from
# several threads at once; only the library and that test are built.
test-tsan: deps
	cmake -S . -B build/tsan $(OSD_ARGS) -DCMAKE_BUILD_TYPE=RelWithDebInfo -DSPIA_TSAN=ON
	cmake --build build/tsan --target test_concurrent --parallel 2
	TSAN_OPTIONS=halt_on_error=1:second_deadlock_stack=1 build/tsan/tests/c/test_concurrent

# The libFuzzer target (tests/fuzz/fuzz_spia.c, clang, AddressSanitizer,
# UndefinedBehaviorSanitizer, leak checking) for FUZZ_SECONDS, from the seed
# corpus (tests/data, written by test_fuzz_replay --seeds), the regression
# inputs and what earlier runs added to build/fuzz/corpus.  A crash stops it
# and leaves the input in build/fuzz/crashes/; copied to
# tests/fuzz/regressions/ it is replayed by every `make test-c` from then on.
FUZZ_SECONDS ?= 600
FUZZ_TARGET = build/fuzz/tests/fuzz/spia_fuzz
fuzz: build
	cmake -S . -B build/fuzz $(OSD_ARGS) -DCMAKE_BUILD_TYPE=RelWithDebInfo -DCMAKE_C_COMPILER=clang -DCMAKE_CXX_COMPILER=clang++ \
	  -DSPIA_FUZZ=ON -DSPIA_TESTS=OFF
	cmake --build build/fuzz --target spia_fuzz --parallel 2
	mkdir -p build/fuzz/seeds build/fuzz/corpus build/fuzz/crashes
	build/cmake/tests/c/test_fuzz_replay --seeds build/fuzz/seeds
	ASAN_OPTIONS=detect_leaks=1:abort_on_error=1 UBSAN_OPTIONS=print_stacktrace=1:halt_on_error=1 \
	  $(FUZZ_TARGET) -max_total_time=$(FUZZ_SECONDS) -timeout=60 -rss_limit_mb=2048 -malloc_limit_mb=2048 -max_len=20000 \
	  -print_final_stats=1 -artifact_prefix=build/fuzz/crashes/ build/fuzz/corpus build/fuzz/seeds tests/fuzz/regressions

test-fuzz:
	$(MAKE) fuzz FUZZ_SECONDS=60

test-python: build
	SUBDIV_PIA_ADDON_DIR=build/addon $(PYTHON) -m pytest -q tests/python

# The packages as shipped: ELF and PE audits, loading with the system's
# libraries hidden or Blender's preloaded, clean Debian 11 and 12/13 chroots
# (tests/package/run.py); the wheels, sdist and extensions: twine,
# auditwheel, their contents and licences, Blender's validator, pip into
# clean venvs of Python 3.9 to 3.13 with numpy 1.x and 2.x and Debian 11's,
# a trimesh client (tests/package/dist.py); the Windows wheel in official
# Windows CPython 3.11 and 3.13 under Wine, its cages the Linux wheel's
# (tests/package/windows_python.py).
test-package: package
	$(SUDO) $(PYTHON) tests/package/run.py $(LEGACY) $(WINDOWS_LEGACY)
	$(SUDO) $(PYTHON) tests/package/dist.py
	$(SUDO) $(PYTHON) tests/package/windows_python.py

# The Blender suite against the installed package, in every Blender here:
# Debian's, the other Debian release's (chroot), PyPI's bpy builds; the
# extension (through Blender's installer, which installs its wheel) from
# 4.2 on, the legacy add-on before.  Besides, part of the suite in PyPI's
# official Windows bpy 4.2, 4.5 and 5.3 under Wine, with the Windows
# extension (tools/blenders.py's WINDOWS_SUITE).
# BLENDER_SUITE_FLAGS=--discard-venvs keeps one or two bpy venvs (1 GB each)
# on disk at a time instead of all of them.
BLENDER_SUITE_FLAGS ?=
test-blender: package
	$(SUDO) $(PYTHON) tools/blenders.py test $(BLENDER_SUITE_FLAGS) $(EXTENSION) --legacy $(LEGACY)

# The operator and the panel in Blender's window (Xvfb, software OpenGL), in
# the Blenders that have one (Debian's, on the machine and in the chroot):
# the operator runs modal, the window stays live, Esc cancels and leaves
# nothing; the panel draws without an error, shows at its top what applies
# and no more, and is photographed (build/window/<Blender>/panel_*.png).
test-window: package
	$(SUDO) $(PYTHON) tools/blenders.py window $(LEGACY)

blenders:
	$(PYTHON) tools/blenders.py list

demo: build
	mkdir -p out
	$(BLENDER_RUN) --python build/addon/subdiv_pia/cli.py -- tests/data/mushroom.obj out/mushroom_interpolated.blend
	$(BLENDER_RUN) --python bench/render_comparison.py -- tests/data/mushroom.obj out/mushroom_comparison.png

bench: build bench-scale bench-solve bench-closest
	$(PYTHON) bench/bench_interpolate.py
	$(PYTHON) bench/bench_loop_papers.py
	$(PYTHON) bench/bench_doosabin.py
	$(BLENDER_RUN) --python bench/bench_fit.py
	$(BLENDER_RUN) --python bench/render_fit.py -- --case bunny --scale 2e-3
	$(BLENDER_RUN) --python bench/render_fit.py -- --case dragon --scale 2e-3

# Speed and scale (bench/bench_scale.py; BENCH_QUICK=1 for a short subset).  The
# OpenSubdiv helper is built in its own tree, with -DSPIA_BENCH=ON.
bench-scale: build
	cmake -S . -B build/bench $(OSD_ARGS) -DCMAKE_BUILD_TYPE=Release -DSPIA_BENCH=ON -DSPIA_TESTS=OFF
	cmake --build build/bench --target spia_bench_osd --parallel 2
	$(PYTHON) bench/bench_scale.py --blender $(BLENDER)

# The solve alone, every Gauss-Seidel variant beside GS-PIA on 1 and 2
# threads (bench/bench_solve.py; writes out/bench/solve.md).
bench-solve: build
	$(PYTHON) bench/bench_solve.py

# Memory that settings make grow: creased meshes (every crease 0.7 to 0.99)
# in child processes under a 2 GB address-space limit, time and peak per
# cell, and the refinements' bytes per face behind the library's estimates
# (bench/bench_creases.py).
bench-creases: build
	$(PYTHON) bench/bench_creases.py

# Live cages: the update time per edit at 1k, 10k and 50k vertices.
bench-live: build
	$(BLENDER_RUN) --python bench/bench_live.py

# The hard set (bench/bench_hard.py): stencils + solve per vertex, one thread,
# at qualities 1, 3, 6 and 10 with and without creases, on messy meshes
# (high-valence fans, non-manifold vertices and edges, large n-gons, darts,
# shuffled scans, printer beds and parts from Debian packages, which are
# downloaded with apt-get into build/meshes-debian the first time), each case
# in its own process with a time budget.  The table goes to out/bench/hard.md;
# `bench/bench_hard.py --quick --only NAME` for a short run.
bench-hard: build
	$(PYTHON) bench/bench_hard.py

# The surface fit against cage size (6k to 100k vertices) and scan size (0.2M
# to 7.3M triangles), each case in a process of its own, from the call to
# the new object, by phase, with peak memory (bench/bench_fit_scale.py; the
# scans and cages are made once and cached in out/bench/fit_scale/).  Writes
# out/bench/fit_scale.md, .json and the log-log plot fit_scale.png.
# FIT_SCALE_ARGS=--grid full for every pair, --grid target for the 50k cage
# on the two largest scans.
FIT_SCALE_ARGS ?=
bench-fit-scale: build
	$(BLENDER_RUN) --python bench/bench_fit_scale.py -- $(FIT_SCALE_ARGS)
	$(PYTHON) bench/plot_fit_scale.py

# spia_scan_create by phase and the fit's closest-point queries on the cached
# scans (bench/bench_scan_scale.c, scan.c and bvh.c compiled in), for this
# tree and, side by side, for git revision SCAN_BASE (default HEAD).
SCAN_BASE ?= HEAD
SCAN_CASES ?= dragon_s2 dragon_s1t1
bench-scan: build
	$(BLENDER_RUN) --python bench/bench_fit_scale.py -- --export-scan-data $(SCAN_CASES)
	cmake -S . -B build/bench $(OSD_ARGS) -DCMAKE_BUILD_TYPE=Release -DSPIA_BENCH=ON -DSPIA_TESTS=OFF
	cmake --build build/bench --target spia_bench_scan --parallel 2
	rm -rf build/bench/scan_base && mkdir -p build/bench/scan_base
	for f in scan.c bvh.c bvh.h threads.c threads.h status.c message.c internal.h; do \
	  git show $(SCAN_BASE):csrc/src/$$f > build/bench/scan_base/$$f; done
	git show $(SCAN_BASE):csrc/src/clock.c > build/bench/scan_base/clock.c 2>/dev/null || \
	  : > build/bench/scan_base/clock.c  # (before clock.c, status.c held the clock)
	grep -q spia__scan_timings build/bench/scan_base/scan.c || \
	  printf '%s\n' 'void spia__scan_timings(const void *s, double *t);' \
	  'void spia__scan_timings(const void *s, double *t) { (void)s; for (int i = 0; i < 4; ++i) t[i] = 0; }' \
	  >> build/bench/scan_base/scan.c
	$(CC) -O3 -DNDEBUG -pthread -Icsrc/include -Ibuild/bench/scan_base bench/bench_scan_scale.c \
	  build/bench/scan_base/scan.c build/bench/scan_base/bvh.c build/bench/scan_base/threads.c \
	  build/bench/scan_base/status.c build/bench/scan_base/clock.c build/bench/scan_base/message.c -lm \
	  -o build/bench/spia_bench_scan_base
	d=$$(ls -td out/bench/fit_scale/blender-* | head -1); for s in $(SCAN_CASES); do for i in 1 2; do \
	  echo "== $$s, $(SCAN_BASE)"; build/bench/spia_bench_scan_base $$d/$$s.bin $$d/queries_50000.bin --reps 1; \
	  echo "== $$s, this tree"; build/bench/bench/spia_bench_scan $$d/$$s.bin $$d/queries_50000.bin --reps 1; \
	done; done

# Closest points: the library's hierarchy against Embree's point query (the
# system's Embree 4 or 3, linked into the benchmark only; without one the
# hierarchy is measured alone) on the bunny and dragon scans and a synthetic
# one of 4 million triangles.  The table goes to out/bench/closest.md.
bench-closest: deps
	cmake -S . -B build/bench $(OSD_ARGS) -DCMAKE_BUILD_TYPE=Release -DSPIA_BENCH=ON -DSPIA_TESTS=OFF
	cmake --build build/bench --target spia_bench_closest --parallel 2
	mkdir -p out/bench
	build/bench/bench/spia_bench_closest --out out/bench/closest.md

clean:
	$(PYTHON) setup.py clean
