#!/usr/bin/env python3
# SPDX-License-Identifier: GPL-3.0-or-later
"""Builds what is shipped: the self-contained native libraries, the Python
distribution around them and the Blender packages.

    python3 tools/package.py all       # everything below, then dist/repo/
    python3 tools/package.py linux     # the Linux x64 library and what is made of it
    python3 tools/package.py windows   # the Windows x64 library (mingw-w64, tested under Wine) ...
    python3 tools/package.py macos     # the macOS arm64 and x86_64 libraries (Zig), audited ...

What is made of each platform's library:
- the wheel dist/subdiv_pia-<version>-py3-none-<tag>.whl (`pip install`,
  `import spia`): the binding (python/spia) and the library, the licences of
  everything inside in its metadata;
- the extension dist/subdiv_pia-<version>-<platform>.zip for Blender 4.2 and
  newer: the pure Python add-on and that wheel under ./wheels/, built by
  Blender's own `extension build --split-platforms` and checked by its
  validator in strict mode;
- the legacy add-on dist/subdiv_pia-<version>-legacy-<platform>.zip for
  Blender 3.4 to 4.1, which take no wheels: the binding and the library
  inside the add-on's folder.
Besides: the sdist dist/subdiv_pia-<version>.tar.gz (scikit-build-core over
CMakeLists.txt, pyproject.toml), whose metadata the wheels carry, and
dist/repo/, a static extension repository listing the four extensions.

The Linux library is built in a Debian 11 (bullseye) chroot (glibc 2.31;
the symbols it takes from glibc are 2.17's or older, manylinux_2_17), with OpenSubdiv 3.6.0 (the version
official Blender 4.1 to 5.0 bundle) compiled from Debian's source package
into a static archive, and the C++ runtime linked in statically (see
SPIA_PACKAGE in CMakeLists.txt).  The C tests are built and run there too,
against that library.

Everything slow (the chroot, the source package, OpenSubdiv's build) is
kept under build/ and reused while its inputs are the same.
"""
import base64
import glob
import hashlib
import json
import os
import re
import shutil
import subprocess
import sys
import zipfile

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import debian  # noqa: E402

ROOT = debian.ROOT
BUILD = debian.BUILD
DIST = os.path.join(ROOT, "dist")
SRC = os.path.join(BUILD, "src")
OPENSUBDIV_VERSION = "3.6.0"
OPENSUBDIV_DIR = os.path.join(SRC, "opensubdiv-" + OPENSUBDIV_VERSION)
# The oldest Debian that can still be fetched sets the glibc floor.
BUILD_SUITE, GLIBC_FLOOR = "bullseye", "2.31"
BUILD_PACKAGES = ["g++", "cmake", "make", "file"]
LIBRARY_NAMES = {"linux-x64": "libsubdiv_pia.so", "windows-x64": "subdiv_pia.dll", "macos-arm64": "libsubdiv_pia.dylib",
                 "macos-x64": "libsubdiv_pia.dylib"}
# OpenSubdiv's core only: no OpenMP, TBB, GPU or example code.
OPENSUBDIV_OPTIONS = ["-D%s=ON" % o for o in (
    "NO_OMP", "NO_TBB", "NO_CUDA", "NO_OPENCL", "NO_CLEW", "NO_OPENGL", "NO_DX", "NO_METAL", "NO_GLFW",
    "NO_PTEX", "NO_EXAMPLES", "NO_TUTORIALS", "NO_REGRESSION", "NO_TESTS", "NO_GLTESTS", "NO_DOC",
    "NO_MACOS_FRAMEWORK")] + ["-DCMAKE_BUILD_TYPE=Release", "-DCMAKE_POSITION_INDEPENDENT_CODE=ON"]


def version():
    """The add-on's version, from its manifest (the one place it is written)."""
    text = open(os.path.join(ROOT, "addon", "blender_manifest.toml")).read()
    return re.search(r'^version\s*=\s*"([^"]+)"', text, re.M).group(1)


def package_name(platform):
    return "subdiv_pia-%s-%s.zip" % (version(), platform)


# --------------------------------------------------------------------------
# OpenSubdiv's source, from Debian
# --------------------------------------------------------------------------

def opensubdiv_source():
    """Debian's source package of OpenSubdiv 3.6.0, unpacked (with Debian's
    patches) at build/src/opensubdiv-3.6.0.  Fetched through a private apt
    sources list, so the machine's own apt setup is left alone."""
    stamp = os.path.join(OPENSUBDIV_DIR, ".subdiv_pia-unpacked")
    if os.path.exists(stamp):
        return OPENSUBDIV_DIR
    apt = os.path.join(SRC, "apt")
    for sub in ("lists/partial", "cache/archives/partial"):
        os.makedirs(os.path.join(apt, sub), exist_ok=True)
    sources = os.path.join(apt, "sources.list")
    uri = debian.mirror()
    with open(sources, "w") as f:
        # trixie (Debian 13) ships 3.6.0; sid in case it has moved on there.
        f.write("deb-src %s trixie main\ndeb-src %s sid main\n" % (uri, uri))
    options = ["-o", "Dir::Etc::SourceList=" + sources, "-o", "Dir::Etc::SourceParts=/dev/null",
               "-o", "Dir::State::Lists=" + os.path.join(apt, "lists"),
               "-o", "Dir::Cache=" + os.path.join(apt, "cache"), "-o", "APT::Sandbox::User=root"]
    debian.run(["apt-get", "-qq"] + options + ["update"])
    listing = subprocess.run(["apt-cache"] + options + ["showsrc", "opensubdiv"], check=True,
                             stdout=subprocess.PIPE, text=True).stdout
    versions = [v for v in re.findall(r"^Version: (\S+)", listing, re.M)
                if v.split("-")[0] == OPENSUBDIV_VERSION]
    if not versions:
        raise RuntimeError("no source package of OpenSubdiv %s on %s (found %s)" % (
            OPENSUBDIV_VERSION, uri, ", ".join(re.findall(r"^Version: (\S+)", listing, re.M)) or "none"))
    download = os.path.join(SRC, "download")
    shutil.rmtree(download, ignore_errors=True)
    os.makedirs(download)
    debian.run(["apt-get", "-qq"] + options + ["source", "--download-only", "opensubdiv=" + versions[0]],
               cwd=download)
    dsc = glob.glob(os.path.join(download, "opensubdiv_*.dsc"))[0]
    shutil.rmtree(OPENSUBDIV_DIR, ignore_errors=True)
    # apt checked the files against the signed Sources index; the .dsc's own
    # signature would need the uploaders' keyring.
    debian.run(["dpkg-source", "--no-check", "-x", dsc, OPENSUBDIV_DIR], stdout=subprocess.DEVNULL)
    with open(stamp, "w") as f:
        f.write(versions[0] + "\n")
    return OPENSUBDIV_DIR


def host_opensubdiv(log=sys.stdout):
    """OpenSubdiv 3.6.0's static core built with this machine's compiler from
    the same source package as the shipped libraries, at
    build/osd/host/lib/libosdCPU.a; returns (source tree, archive).

    Every build of the library (development, sanitizers, fuzzing,
    benchmarks) links this one instead of the system's OpenSubdiv, so that
    each computes what the package computes: Debian 12's OpenSubdiv 3.5
    gives other limit points at valence-2 vertices and crashes in
    Bfr::IrregularPatchBuilder on OpenSubdiv's own catmark_val2_interior."""
    src = opensubdiv_source()
    osd = os.path.join(BUILD, "osd", "host")
    archive = os.path.join(osd, "lib", "libosdCPU.a")
    stamp = os.path.join(osd, ".subdiv_pia-built")
    if not os.path.exists(stamp):
        os.makedirs(osd, exist_ok=True)
        subprocess.run(["cmake", "-S", src, "-B", osd] + OPENSUBDIV_OPTIONS, check=True,
                       stdout=subprocess.DEVNULL, stderr=log)
        subprocess.run(["cmake", "--build", osd, "--target", "osd_static_cpu", "--parallel", str(os.cpu_count() or 2)],
                       check=True, stdout=subprocess.DEVNULL, stderr=log)
        with open(stamp, "w") as f:
            f.write(OPENSUBDIV_VERSION + "\n")
    return src, archive


def opensubdiv_cmake_args(log=sys.stderr):
    """The CMake arguments that point a build at host_opensubdiv()."""
    src, archive = host_opensubdiv(log)
    return ["-DOPENSUBDIV_INCLUDE_DIR=" + src, "-DOPENSUBDIV_CPU_LIBRARY=" + archive]


# --------------------------------------------------------------------------
# The Linux library
# --------------------------------------------------------------------------

def build_linux(run_tests=True):
    """Builds libsubdiv_pia.so in the bullseye chroot; returns its path."""
    out = os.path.join(BUILD, "package", "linux-x64")
    os.makedirs(out, exist_ok=True)
    opensubdiv_source()
    root = debian.chroot(BUILD_SUITE + "-build", BUILD_SUITE, BUILD_PACKAGES)
    inner = "/src/build/package/linux-x64"
    osd_src = "/src/build/src/opensubdiv-" + OPENSUBDIV_VERSION
    steps = [
        "set -e",
        # OpenSubdiv's static core, once.
        "if [ ! -f {o}/osd/lib/libosdCPU.a ]; then cmake -S {s} -B {o}/osd {opts} >{o}/osd-configure.log"
        " && cmake --build {o}/osd --target osd_static_cpu --parallel 2 >{o}/osd-build.log; fi",
        "cmake -S /src -B {o}/cmake -DSPIA_PACKAGE=ON -DCMAKE_BUILD_TYPE=Release -DSPIA_TESTS=ON"
        " -DOPENSUBDIV_INCLUDE_DIR={s} -DOPENSUBDIV_CPU_LIBRARY={o}/osd/lib/libosdCPU.a >{o}/configure.log",
        "cmake --build {o}/cmake --parallel 2",
        "strip --strip-unneeded -o {o}/libsubdiv_pia.so {o}/cmake/libsubdiv_pia.so",
        # The GCC runtime's licence, for the zip: the copyright file of the
        # compiler whose libstdc++ and libgcc went into the library.
        "cp $(ls /usr/share/doc/gcc-*-base/copyright | sort -V | tail -n 1) {o}/gcc-runtime-copyright.txt",
        "ldd --version | head -n 1 > {o}/glibc.txt",
    ]
    if run_tests:
        steps.append("cd {o}/cmake && ctest --output-on-failure --parallel 2")
    script = "\n".join(steps).format(o=inner, s=osd_src, opts=" ".join(OPENSUBDIV_OPTIONS))
    debian.in_chroot(root, script, binds=[(ROOT, "/src")])
    return os.path.join(out, "libsubdiv_pia.so")


# --------------------------------------------------------------------------
# The Windows library (cross-built with mingw-w64, tested under Wine)
# --------------------------------------------------------------------------

WINDOWS_TOOLCHAIN = os.path.join(ROOT, "cmake", "mingw-w64-x86_64.cmake")


def wine_environment():
    prefix = os.path.join(BUILD, "wine")
    os.makedirs(prefix, exist_ok=True)
    return dict(os.environ, WINEPREFIX=prefix, WINEDEBUG="-all", WINEDLLOVERRIDES="mscoree,mshtml=")


def build_windows(run_tests=True):
    """Builds subdiv_pia.dll with the machine's mingw-w64 (the same sources,
    OpenSubdiv's core from the same source package, the GCC runtime and
    winpthreads linked in statically) and runs the C tests under Wine;
    returns the DLL's path."""
    out = os.path.join(BUILD, "package", "windows-x64")
    os.makedirs(out, exist_ok=True)
    src = opensubdiv_source()
    osd = os.path.join(out, "osd")
    archive = os.path.join(osd, "lib", "libosdCPU.a")
    toolchain = "-DCMAKE_TOOLCHAIN_FILE=" + WINDOWS_TOOLCHAIN
    if not os.path.exists(archive):
        debian.run(["cmake", "-S", src, "-B", osd, toolchain, "-DCMAKE_CXX_FLAGS=-D_USE_MATH_DEFINES"] +
                   OPENSUBDIV_OPTIONS, stdout=subprocess.DEVNULL)
        debian.run(["cmake", "--build", osd, "--target", "osd_static_cpu", "--parallel", "2"],
                   stdout=subprocess.DEVNULL)
    cmake = os.path.join(out, "cmake")
    debian.run(["cmake", "-S", ROOT, "-B", cmake, toolchain, "-DSPIA_PACKAGE=ON", "-DCMAKE_BUILD_TYPE=Release",
                "-DSPIA_TESTS=ON", "-DOPENSUBDIV_INCLUDE_DIR=" + src, "-DOPENSUBDIV_CPU_LIBRARY=" + archive],
               stdout=subprocess.DEVNULL)
    debian.run(["cmake", "--build", cmake, "--parallel", "2"])
    dll = os.path.join(out, "subdiv_pia.dll")
    debian.run(["x86_64-w64-mingw32-strip", "--strip-unneeded", "-o", dll, os.path.join(cmake, "bin", "subdiv_pia.dll")])
    gcc = subprocess.run(["x86_64-w64-mingw32-gcc-posix", "--version"], stdout=subprocess.PIPE, text=True).stdout
    with open(os.path.join(out, "compiler.txt"), "w") as f:
        f.write(gcc.splitlines()[0] + "\n")
    # The cross compiler's licence (its runtime is GCC's, with the runtime
    # library exception), else the native GCC's, which says the same.
    copyrights = (glob.glob("/usr/share/doc/gcc-mingw-w64-base/copyright") +
                  sorted(glob.glob("/usr/share/doc/gcc-*-base/copyright")))
    shutil.copy2(copyrights[0], os.path.join(out, "gcc-runtime-copyright.txt"))
    winpthreads = "/usr/share/doc/mingw-w64-x86-64-dev/copyright"
    if os.path.exists(winpthreads):
        shutil.copy2(winpthreads, os.path.join(out, "mingw-w64-copyright.txt"))
    if run_tests:
        # A test that fails is run once more: Wine has failed to start a
        # test program at all (no output, 0.00 s) once in many runs, and a
        # real failure fails twice.
        env = wine_environment()
        # One Wine server for the whole run, started before it: else the
        # first test starts it, two tests starting at once can race to (one
        # fails at once), and the server and Wine's services keep the first
        # test's output pipe open, so that ctest sees it end only with the
        # last test, one of its two slots taken throughout.
        debian.run(["wineserver", "-p"], env=env)
        try:
            debian.run(["wine", "wineboot", "--init"], env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
            debian.run(["ctest", "--output-on-failure", "--parallel", "2", "--repeat", "until-pass:2"], cwd=cmake,
                       env=env)
        finally:
            subprocess.run(["wineserver", "-k"], env=env)
    return dll


# --------------------------------------------------------------------------
# The macOS libraries (cross-built with Zig; nothing here can run them)
# --------------------------------------------------------------------------

MACOS_TOOLCHAIN = os.path.join(ROOT, "cmake", "zig-macos.cmake")
MACOS_VENV = os.path.join(BUILD, "venv-macos")
# Zig 0.17 (clang 22) carries macOS's libc headers, libSystem's stubs and
# libc++; LIEF reads the Mach-O files for tests/package/macho_audit.py.
MACOS_TOOLS = ["ziglang>=0.17,<0.18", "lief>=1.0,<2"]
MACOS_TARGETS = {"macos-arm64": "aarch64-macos.11.0", "macos-x64": "x86_64-macos.11.0"}


def macos_python():
    """build/venv-macos's Python, with Zig and LIEF from PyPI (made once)."""
    return tool_venv(MACOS_VENV, MACOS_TOOLS)


def build_macos(platform, run_tests=True):
    """Builds libsubdiv_pia.dylib for `platform` (macos-arm64, macos-x64;
    macOS 11 and newer) with Zig's clang and linker: OpenSubdiv's core from
    the same source package, compiled with hidden visibility, and Zig's
    libc++ linked in statically (see SPIA_PACKAGE's APPLE branch in
    CMakeLists.txt).  The C tests are built too; nothing can run them here,
    so with run_tests the library and the test programs are audited instead
    (tests/package/macho_audit.py: libSystem only, the API only, macOS 11,
    the arm64 signature's page hashes).  Returns the library's path."""
    python = macos_python()
    out = os.path.join(BUILD, "package", platform)
    os.makedirs(out, exist_ok=True)
    src = opensubdiv_source()
    zig = ["-DCMAKE_TOOLCHAIN_FILE=" + MACOS_TOOLCHAIN, "-DZIG_TARGET=" + MACOS_TARGETS[platform],
           "-DZIG_PYTHON=" + python, "-DZIG_WRAPPER_DIR=" + os.path.join(out, "zig"),
           "-DZIG_CACHE_DIR=" + os.path.join(BUILD, "zig-cache")]
    osd = os.path.join(out, "osd")
    archive = os.path.join(osd, "lib", "libosdCPU.a")
    # Hidden: Zig's linker ignores -exported_symbols_list, so whatever of
    # OpenSubdiv had default visibility would be exported.
    osd_args = zig + ["-DCMAKE_CXX_FLAGS=-fvisibility=hidden -fvisibility-inlines-hidden"] + OPENSUBDIV_OPTIONS
    stamp = os.path.join(osd, ".subdiv_pia-built")
    if not (os.path.exists(archive) and os.path.exists(stamp) and open(stamp).read() == "\n".join(osd_args)):
        debian.run(["cmake", "-S", src, "-B", osd] + osd_args, stdout=subprocess.DEVNULL)
        debian.run(["cmake", "--build", osd, "--target", "osd_static_cpu", "--parallel", "2"],
                   stdout=subprocess.DEVNULL)
        with open(stamp, "w") as f:
            f.write("\n".join(osd_args))
    cmake = os.path.join(out, "cmake")
    debian.run(["cmake", "-S", ROOT, "-B", cmake] + zig +
               ["-DSPIA_PACKAGE=ON", "-DCMAKE_BUILD_TYPE=Release", "-DSPIA_TESTS=ON",
                "-DOPENSUBDIV_INCLUDE_DIR=" + src, "-DOPENSUBDIV_CPU_LIBRARY=" + archive], stdout=subprocess.DEVNULL)
    debian.run(["cmake", "--build", cmake, "--parallel", "2"])
    # A plain copy: the linker stripped it (-x -S) and, on arm64, signed it;
    # strip or install_name_tool now would break that signature.
    dylib = os.path.join(out, "libsubdiv_pia.dylib")
    shutil.copy2(os.path.join(cmake, "libsubdiv_pia.dylib"), dylib)
    zig_version = subprocess.run([python, "-m", "ziglang", "version"], check=True, stdout=subprocess.PIPE,
                                 text=True).stdout.strip()
    with open(os.path.join(out, "compiler.txt"), "w") as f:
        f.write("zig %s (PyPI ziglang), target %s\n" % (zig_version, MACOS_TARGETS[platform]))
    # The licence of the C++ runtime inside (LLVM's libc++ and libc++abi,
    # both Apache-2.0 WITH LLVM-exception), from the Zig that linked it.
    zig_lib = subprocess.run([python, "-c", "import os, ziglang; print(os.path.dirname(ziglang.__file__))"],
                             check=True, stdout=subprocess.PIPE, text=True).stdout.strip()
    shutil.copy2(os.path.join(zig_lib, "lib", "libcxx", "LICENSE.TXT"), os.path.join(out, "llvm-libcxx-license.txt"))
    if run_tests:
        programs = sorted(p for p in glob.glob(os.path.join(cmake, "tests", "c", "test_*"))
                          if os.path.isfile(p) and os.access(p, os.X_OK))
        debian.run([python, os.path.join(ROOT, "tests", "package", "macho_audit.py"), dylib] + programs)
    return dylib


def build_macos_arm64(run_tests=True):
    return build_macos("macos-arm64", run_tests)


def build_macos_x64(run_tests=True):
    return build_macos("macos-x64", run_tests)


# --------------------------------------------------------------------------
# The Python distribution: the sdist and one wheel per platform
# --------------------------------------------------------------------------

# The wheel's platform tag for each extension platform: the oldest systems
# each library runs on (glibc 2.17's symbols at most, the linker's minimum
# macOS 11.0, tests/package/macho_audit.py).
WHEEL_TAGS = {"linux-x64": "manylinux_2_17_x86_64", "windows-x64": "win_amd64",
              "macos-arm64": "macosx_11_0_arm64", "macos-x64": "macosx_11_0_x86_64"}
# What is inside each wheel, as an SPDX expression: the project, OpenSubdiv
# (Pixar's modified Apache 2.0) and the runtime each toolchain links in
# (GCC's with its runtime exception; mingw-w64's CRT startup and winpthreads;
# LLVM's libc++ and libc++abi).
LICENSE_EXPRESSIONS = {
    "linux-x64": "GPL-3.0-or-later AND Pixar AND GPL-3.0-or-later WITH GCC-exception-3.1",
    "windows-x64": "GPL-3.0-or-later AND Pixar AND GPL-3.0-or-later WITH GCC-exception-3.1 AND ZPL-2.1 AND MIT "
                   "AND BSD-3-Clause",
    "macos-arm64": "GPL-3.0-or-later AND Pixar AND Apache-2.0 WITH LLVM-exception",
    "macos-x64": "GPL-3.0-or-later AND Pixar AND Apache-2.0 WITH LLVM-exception",
}
DIST_VENV = os.path.join(BUILD, "venv-dist")
# The sdist's backend and the checks of what is shipped (tests/package/dist.py).
DIST_TOOLS = ["build>=1.2", "scikit-build-core>=0.11", "twine>=6.1", "auditwheel>=6.1", "packaging>=24.2"]
# What the sdist is made from (pyproject.toml's backend builds it from a
# copy of these alone, so that nothing under build/ is walked).
SDIST_FILES = ["pyproject.toml", "CMakeLists.txt", "LICENSE", "README.md", "cmake", "csrc", "python",
               "addon/blender_manifest.toml"]


def tool_venv(venv, tools):
    """A virtual environment under build/ with `tools` from PyPI (made once);
    returns its Python."""
    python = os.path.join(venv, "bin", "python")
    stamp = os.path.join(venv, ".subdiv_pia-tools")
    wanted = " ".join(tools) + "\n"
    if not (os.path.exists(stamp) and open(stamp).read() == wanted and os.path.exists(python)):
        if not os.path.exists(python):
            debian.run([python_with_pip(), "-m", "venv", venv])
        debian.run([python, "-m", "pip", "install", "-q", "--disable-pip-version-check"] + tools)
        with open(stamp, "w") as f:
            f.write(wanted)
    return python


def dist_python():
    return tool_venv(DIST_VENV, DIST_TOOLS)


def wheel_name(platform):
    return "subdiv_pia-%s-py3-none-%s.whl" % (version(), WHEEL_TAGS[platform])


def sdist_name():
    return "subdiv_pia-%s.tar.gz" % version()


def build_sdist():
    """dist/subdiv_pia-<version>.tar.gz, built by pyproject.toml's backend."""
    stage = os.path.join(BUILD, "sdist-src")
    shutil.rmtree(stage, ignore_errors=True)
    for name in SDIST_FILES:
        source, target = os.path.join(ROOT, name), os.path.join(stage, name)
        if os.path.isdir(source):
            shutil.copytree(source, target, ignore=shutil.ignore_patterns("__pycache__", "*.pyc"))
        else:
            os.makedirs(os.path.dirname(target), exist_ok=True)
            shutil.copy2(source, target)
    os.makedirs(DIST, exist_ok=True)
    debian.run([dist_python(), "-m", "build", "--sdist", "--outdir", DIST, stage])
    return os.path.join(DIST, sdist_name())


def sdist_metadata(sdist):
    """The core metadata (PKG-INFO) the backend wrote into the sdist."""
    import tarfile
    with tarfile.open(sdist) as tar:
        member = tar.extractfile("subdiv_pia-%s/PKG-INFO" % version())
        return member.read().decode("utf-8")


def wheel_metadata(pkg_info, platform, licence_names):
    """The sdist's metadata with the licence of what this platform's wheel
    holds (its expression, and a License-File line per text)."""
    head, sep, body = pkg_info.partition("\n\n")
    lines = [line for line in head.splitlines() if not line.startswith(("License-Expression:", "License-File:"))]
    at = next(i for i, line in enumerate(lines) if line.startswith("Summary:")) + 1
    lines[at:at] = (["License-Expression: " + LICENSE_EXPRESSIONS[platform]] +
                    ["License-File: " + name for name in licence_names])
    return "\n".join(lines) + sep + body


def _record_hash(data):
    digest = base64.urlsafe_b64encode(hashlib.sha256(data).digest()).rstrip(b"=").decode("ascii")
    return "sha256=" + digest


def binding_files():
    """(name in the wheel, path) of each module of the binding, python/spia/*.py,
    in order of name: what every package carries of it beside the library."""
    folder = os.path.join(ROOT, "python", "spia")
    return [("spia/" + name, os.path.join(folder, name)) for name in sorted(os.listdir(folder))
            if name.endswith(".py")]


def write_wheel(platform, library, pkg_info):
    """dist/subdiv_pia-<version>-py3-none-<tag>.whl around the built library,
    following the wheel specification (the same bytes for the same inputs)."""
    platform_dir = os.path.dirname(library)
    dist_info = "subdiv_pia-%s.dist-info" % version()
    licences = [(os.path.basename(name), path) for name, path in licence_files(platform_dir)]
    files = [(name, open(path, "rb").read(), 0o644) for name, path in binding_files()]
    files.append(("spia/" + LIBRARY_NAMES[platform], open(library, "rb").read(), 0o755))
    files += [("%s/licenses/%s" % (dist_info, name), open(path, "rb").read(), 0o644) for name, path in licences]
    files.append(("%s/METADATA" % dist_info,
                  wheel_metadata(pkg_info, platform, [n for n, _p in licences]).encode("utf-8"), 0o644))
    files.append(("%s/WHEEL" % dist_info, ("Wheel-Version: 1.0\nGenerator: subdiv_pia tools/package.py\n"
                                           "Root-Is-Purelib: false\nTag: py3-none-%s\n" % WHEEL_TAGS[platform])
                  .encode("ascii"), 0o644))
    record = "".join("%s,%s,%d\n" % (name, _record_hash(data), len(data)) for name, data, _mode in files)
    files.append(("%s/RECORD" % dist_info, (record + "%s/RECORD,,\n" % dist_info).encode("utf-8"), 0o644))
    os.makedirs(DIST, exist_ok=True)
    path = os.path.join(DIST, wheel_name(platform))
    with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED, compresslevel=9) as zf:
        for name, data, mode in files:
            info = zipfile.ZipInfo(name, date_time=(2020, 1, 1, 0, 0, 0))
            info.external_attr = (0o100000 | mode) << 16
            info.compress_type = zipfile.ZIP_DEFLATED
            zf.writestr(info, data)
    return path


# --------------------------------------------------------------------------
# The Blender packages
# --------------------------------------------------------------------------

def extension_name(platform):
    """As Blender's `extension build --split-platforms` names it."""
    return "subdiv_pia-%s-%s.zip" % (version(), platform.replace("-", "_"))


def legacy_name(platform):
    return "subdiv_pia-%s-legacy-%s.zip" % (version(), platform.replace("-", "_"))


def manifest_for(platforms, wheels=()):
    """addon/blender_manifest.toml for `platforms`, listing `wheels` (file names under ./wheels/)."""
    text = open(os.path.join(ROOT, "addon", "blender_manifest.toml")).read()
    line = 'platforms = [%s]' % ", ".join('"%s"' % p for p in platforms)
    if wheels:
        line += "\nwheels = [\n%s]" % "".join('  "./wheels/%s",\n' % w for w in wheels)
    text, count = re.subn(r"^platforms\s*=.*$", line, text, flags=re.M)
    assert count == 1, "blender_manifest.toml needs one platforms line"
    return text


def licence_files(platform_dir):
    """(name in the legacy zip, path) of every licence text a package carries."""
    files = [("LICENSE", os.path.join(ROOT, "LICENSE")),
             ("licenses/OpenSubdiv-LICENSE.txt", os.path.join(OPENSUBDIV_DIR, "LICENSE.txt")),
             ("licenses/OpenSubdiv-NOTICE.txt", os.path.join(OPENSUBDIV_DIR, "NOTICE.txt")),
             ("licenses/GCC-runtime-copyright.txt", os.path.join(platform_dir, "gcc-runtime-copyright.txt"))]
    if os.path.exists(os.path.join(platform_dir, "llvm-libcxx-license.txt")):  # macOS: Zig's libc++, not GCC's
        files[-1] = ("licenses/LLVM-libcxx-LICENSE.txt", os.path.join(platform_dir, "llvm-libcxx-license.txt"))
    if os.path.exists(os.path.join(platform_dir, "mingw-w64-copyright.txt")):  # winpthreads
        files.append(("licenses/mingw-w64-copyright.txt", os.path.join(platform_dir, "mingw-w64-copyright.txt")))
    for _name, path in files:
        if not os.path.isfile(path):
            raise RuntimeError("licence text missing: %s" % path)
    return files


def _addon_copy(stage):
    shutil.rmtree(os.path.dirname(stage), ignore_errors=True)
    shutil.copytree(os.path.join(ROOT, "addon"), stage,
                    ignore=shutil.ignore_patterns("__pycache__", "*.pyc", "*.so", "*.dll", "*.dylib"))


def _zip_folder(stage, archive):
    os.makedirs(os.path.dirname(archive), exist_ok=True)
    with zipfile.ZipFile(archive, "w", zipfile.ZIP_DEFLATED, compresslevel=9) as zf:
        for folder, dirs, files in os.walk(stage):
            dirs.sort()
            for name in sorted(files):
                path = os.path.join(folder, name)
                zf.write(path, os.path.relpath(path, os.path.dirname(stage)))
    return archive


def assemble_legacy(platform, library):
    """dist/subdiv_pia-<version>-legacy-<platform>.zip for Blender 3.4 to 4.1:
    the add-on with the binding and `library` inside (subdiv_pia/spia/) and
    the licence texts."""
    platform_dir = os.path.dirname(library)
    stage = os.path.join(platform_dir, "stage", "subdiv_pia")
    _addon_copy(stage)
    with open(os.path.join(stage, "blender_manifest.toml"), "w") as f:
        f.write(manifest_for([platform]))
    shutil.copytree(os.path.join(ROOT, "python", "spia"), os.path.join(stage, "spia"),
                    ignore=shutil.ignore_patterns("__pycache__", "*.pyc", "*.so", "*.dll", "*.dylib"))
    shutil.copy2(library, os.path.join(stage, "spia", LIBRARY_NAMES[platform]))
    for name, path in licence_files(platform_dir):
        os.makedirs(os.path.dirname(os.path.join(stage, name)), exist_ok=True)
        shutil.copy2(path, os.path.join(stage, name))
    return _zip_folder(stage, os.path.join(DIST, legacy_name(platform)))


def build_extensions(wheels):
    """One extension per platform in `wheels` ({platform: wheel}), each the
    pure Python add-on and that platform's wheel under ./wheels/, made by
    Blender's own `extension build --split-platforms` from one source folder
    whose manifest lists them all; returns {platform: zip}."""
    stage = os.path.join(BUILD, "package", "extension", "subdiv_pia")
    _addon_copy(stage)
    platforms = sorted(wheels)
    with open(os.path.join(stage, "blender_manifest.toml"), "w") as f:
        f.write(manifest_for(platforms, [os.path.basename(wheels[p]) for p in platforms]))
    os.makedirs(os.path.join(stage, "wheels"))
    for p in platforms:
        shutil.copy2(wheels[p], os.path.join(stage, "wheels"))
    shutil.copy2(os.path.join(ROOT, "LICENSE"), os.path.join(stage, "LICENSE"))
    out = os.path.join(BUILD, "package", "extension", "out")
    shutil.rmtree(out, ignore_errors=True)
    os.makedirs(out)
    python, tool, tags = blender_extension_tool()
    debian.run([python, tool, "build", "--source-dir=" + stage, "--output-dir=" + out, "--split-platforms"] +
               (["--valid-tags=" + tags] if tags else []))
    archives = {}
    for p in platforms:
        made = os.path.join(out, extension_name(p))
        if not os.path.isfile(made):
            raise RuntimeError("Blender's extension build made no %s (made: %s)" % (
                extension_name(p), ", ".join(sorted(os.listdir(out))) or "nothing"))
        archives[p] = os.path.join(DIST, extension_name(p))
        shutil.copy2(made, archives[p])
    return archives


# --------------------------------------------------------------------------
# Blender's extension tools (validator, repository index)
# --------------------------------------------------------------------------

def python_with_pip():
    """A Python 3.11 or newer that has pip (Debian's own may not)."""
    for python in (sys.executable, shutil.which("python3"), shutil.which("python3.11"), shutil.which("python3.13")):
        if python and subprocess.run([python, "-c", "import sys, pip; assert sys.version_info >= (3, 11)"],
                                     stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL).returncode == 0:
            return python
    raise RuntimeError("no Python 3.11 or newer with pip to fetch Blender's extension tools (install python3-pip)")


def blender_wheel():
    """The newest official Blender (PyPI's bpy wheel) for this Python, fetched once into build/wheels."""
    wheels = os.path.join(BUILD, "wheels")
    os.makedirs(wheels, exist_ok=True)
    if not glob.glob(os.path.join(wheels, "bpy-*.whl")):
        debian.run([python_with_pip(), "-m", "pip", "download", "-q", "--no-deps", "--only-binary=:all:",
                    "-d", wheels, "bpy"])
    return sorted(glob.glob(os.path.join(wheels, "bpy-*.whl")))[-1]


def blender_extension_tool():
    """(python, blender_ext.py, tags.py) from a Blender 4.2 or newer: the
    machine's, a bpy wheel already unpacked under build/, or the newest bpy
    wheel for this Python, fetched from PyPI once."""
    patterns = ["/usr/share/blender/*/scripts/addons_core/bl_pkg/cli/blender_ext.py",
                os.path.join(BUILD, "bpy", "*", "lib", "python*", "site-packages", "bpy", "*",
                             "scripts", "addons_core", "bl_pkg", "cli", "blender_ext.py"),
                os.path.join(BUILD, "wheels", "bpy-tools", "bpy", "*", "scripts", "addons_core", "bl_pkg",
                             "cli", "blender_ext.py")]
    found = [p for pattern in patterns for p in glob.glob(pattern)]
    if not found:
        wheel = blender_wheel()
        with zipfile.ZipFile(wheel) as zf:
            members = [m for m in zf.namelist()
                       if m.endswith(("bl_pkg/cli/blender_ext.py", "_bpy_internal/extensions/tags.py"))]
            zf.extractall(os.path.join(BUILD, "wheels", "bpy-tools"), members)
        return blender_extension_tool()
    tool = sorted(found)[-1]
    scripts = tool.split(os.sep + "addons_core" + os.sep)[0]
    tags = os.path.join(scripts, "modules", "_bpy_internal", "extensions", "tags.py")
    python = sys.executable if sys.version_info >= (3, 11) else shutil.which("python3")
    return python, tool, tags if os.path.isfile(tags) else ""


def validate(archive):
    python, tool, tags = blender_extension_tool()
    debian.run([python, tool, "validate", "--valid-tags=" + tags, archive])


def repository_index(archives):
    """dist/repo/: the zips and the index Blender reads from a remote repository."""
    repo = os.path.join(DIST, "repo")
    shutil.rmtree(repo, ignore_errors=True)
    os.makedirs(repo)
    for archive in archives:
        shutil.copy2(archive, repo)
    python, tool, _tags = blender_extension_tool()
    debian.run([python, tool, "server-generate", "--repo-dir=" + repo, "--html"])
    with open(os.path.join(repo, "index.json")) as f:
        index = json.load(f)
    return repo, index


BUILDERS = {"linux-x64": build_linux, "windows-x64": build_windows, "macos-arm64": build_macos_arm64,
            "macos-x64": build_macos_x64}
PLATFORMS = list(BUILDERS)


def package(platforms, run_tests=True):
    """The libraries of `platforms`, and the sdist, wheels, extensions,
    legacy zips and dist/repo/ made of them; returns the list of files."""
    if sorted(platforms) == sorted(PLATFORMS):  # a whole release: nothing older stays beside it
        for old in glob.glob(os.path.join(DIST, "subdiv_pia-*")):
            os.remove(old)
    sdist = build_sdist()
    pkg_info = sdist_metadata(sdist)
    wheels, legacy = {}, {}
    for platform in platforms:
        library = BUILDERS[platform](run_tests)
        wheels[platform] = write_wheel(platform, library, pkg_info)
        legacy[platform] = assemble_legacy(platform, library)
    extensions = build_extensions(wheels)
    for archive in extensions.values():
        validate(archive)
    repo, index = repository_index([extensions[p] for p in platforms])
    made = [sdist] + [f for p in platforms for f in (wheels[p], extensions[p], legacy[p])]
    for path in made:
        print("made: %s (%.2f MB)" % (os.path.relpath(path, ROOT), os.path.getsize(path) / 1e6))
    print("repository: %s (%d packages)" % (repo, len(index.get("data", []))))
    return made


def reported(step):
    """Runs step(); a failure becomes a line on stderr and status 1."""
    try:
        step()
    except (subprocess.CalledProcessError, RuntimeError, OSError) as exc:
        print("package.py: %s" % (exc if not isinstance(exc, subprocess.CalledProcessError) else
                                  "a step failed with status %d (its output is above)" % exc.returncode),
              file=sys.stderr)
        return 1
    return 0


def main(argv):
    platforms = {"linux": ["linux-x64"], "windows": ["windows-x64"], "macos": ["macos-arm64", "macos-x64"],
                 "all": PLATFORMS}
    run_tests = "--no-tests" not in argv
    if argv[:1] and argv[0] in platforms:
        return reported(lambda: package(platforms[argv[0]], run_tests=run_tests))
    if argv[:1] == ["version"]:
        print(version())
        return 0
    if argv[:1] == ["opensubdiv-cmake-args"]:
        # The build's own output (and its commands') goes to stderr: stdout
        # is the arguments alone.
        sys.stdout.flush()
        saved = os.dup(1)
        os.dup2(2, 1)
        try:
            args = opensubdiv_cmake_args()
        finally:
            sys.stdout.flush()
            os.dup2(saved, 1)
            os.close(saved)
        print(" ".join(args))
        return 0
    names = {"extension": extension_name, "legacy": legacy_name, "wheel": wheel_name}
    if argv[:1] == ["name"] and len(argv) == 3 and argv[1] in names and argv[2] in BUILDERS:
        print(os.path.join(DIST, names[argv[1]](argv[2])))
        return 0
    print("usage: package.py linux|windows|macos|all [--no-tests] | version | name extension|legacy|wheel PLATFORM"
          " | opensubdiv-cmake-args", file=sys.stderr)
    return 2


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
