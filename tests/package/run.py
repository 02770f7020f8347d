#!/usr/bin/env python3
# SPDX-License-Identifier: GPL-3.0-or-later
"""Tests of the package as it is shipped (`make test-package`):

    python3 tests/package/run.py dist/subdiv_pia-<version>-legacy-linux_x64.zip [dist/...-legacy-windows_x64.zip]

The legacy zips carry the libraries as the wheels and extensions do (the
same files: tests/package/dist.py checks that), unpacked and in the add-on's
folder (subdiv_pia/spia/).

1. audit: the ELF audit of the library (audit_elf.py).
2. host: the unpacked package loads and works here (smoke.py).
3. hidden: the same with every system copy of OpenSubdiv, Embree, TBB and
   libgomp hidden from the process (bound over with /dev/null in a mount
   namespace of its own).
4. preloaded: the same with stand-ins for Embree 4, TBB and OpenSubdiv
   3.6.0 preloaded, as Blender holds them in its process: every call of
   theirs aborts, and the loader's own account (LD_DEBUG=bindings) shows
   each symbol the library looks up bound to the C library, libm or
   libgcc_s; then with Blender's real copies from official bpy builds (the
   wheel tools/package.py fetched, and those unpacked under build/bpy).
6. the Windows zip, if given: its manifest, and its DLL imports only
   Windows system DLLs and exports only the API (audit_pe.py).
5. Debian 11 and the other current release (13 on a Debian 12 machine, else
   12): clean chroots with Python, numpy and pip only, none of those libraries
   installed; the package loads and works there.

Prints a table of the checks and exits 1 if any failed.  Needs root (mount
namespaces, chroots), debootstrap, a C compiler and binutils.
"""
import glob
import os
import re
import shutil
import subprocess
import sys
import tempfile
import zipfile

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(os.path.dirname(HERE))
sys.path.insert(0, os.path.join(ROOT, "tools"))
import debian  # noqa: E402
import audit_elf  # noqa: E402  (beside this file)
import dist  # noqa: E402

WORK = os.path.join(ROOT, "build", "package-test")
MESH = os.path.join(ROOT, "tests", "data", "mushroom.obj")
HEADER = os.path.join(ROOT, "csrc", "include", "subdiv_pia.h")
LIBRARY = "libsubdiv_pia.so"
# What the library may be bound to: the C library's parts, libgcc_s, the loader.
ALLOWED_TARGETS = set(audit_elf.ALLOWED_NEEDED) | {LIBRARY}
HIDDEN = re.compile(r"^lib(osd(CPU|GPU)|embree[34]?|tbb|tbbmalloc|tbbbind|gomp)(_\w+)?\.so")
EMBREE_API = ["rtcNewDevice", "rtcReleaseDevice", "rtcRetainDevice", "rtcGetDeviceError",
              "rtcSetDeviceErrorFunction", "rtcNewScene", "rtcReleaseScene", "rtcCommitScene",
              "rtcAttachGeometry", "rtcNewGeometry", "rtcReleaseGeometry", "rtcCommitGeometry",
              "rtcSetNewGeometryBuffer", "rtcSetSharedGeometryBuffer", "rtcPointQuery", "rtcIntersect1",
              "rtcOccluded1", "rtcGetSceneBounds", "rtcSetGeometryUserData", "rtcNewBVH", "rtcBuildBVH"]
TBB_API = ["_ZN3tbb6detail2r17executeERNS0_2d118task_arena_baseERNS2_9delegate_baseE",
           "_ZN3tbb6detail2r18allocateERPNS0_2d117small_object_poolEm",
           "_ZN3tbb6detail2r15spawnERNS0_2d14taskERNS2_18task_group_contextE",
           "_ZN3tbb6detail2r115allocate_memoryEm", "_ZN3tbb6detail2r117deallocate_memoryEPv",
           "scalable_malloc", "scalable_free"]

results = []


def check(name, ok, detail):
    results.append((name, ok, detail))
    print("%s %s: %s" % ("PASS" if ok else "FAIL", name, detail), flush=True)
    return ok


def smoke(python, parent, env=None, prefix=()):
    cmd = list(prefix) + [python, os.path.join(HERE, "smoke.py"), parent, MESH]
    out = subprocess.run(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env)
    return out.returncode == 0, out.stdout.strip().splitlines()[-1] if out.stdout.strip() else "(no output)"


def system_python():
    for candidate in ("/usr/bin/python3",):
        if os.path.exists(candidate) and subprocess.run([candidate, "-c", "import numpy"]).returncode == 0:
            return candidate
    return sys.executable


def unpack(archive, folder="unpacked"):
    target = os.path.join(WORK, folder)
    shutil.rmtree(target, ignore_errors=True)
    with zipfile.ZipFile(archive) as zf:
        zf.extractall(target)
    return target


def system_library_files():
    """Every system copy of OpenSubdiv, Embree, TBB and libgomp (real files and links)."""
    found = []
    for folder in ("/lib", "/usr/lib", "/lib64", "/usr/lib64", "/usr/local/lib", "/lib/x86_64-linux-gnu",
                   "/usr/lib/x86_64-linux-gnu"):
        for path in glob.glob(os.path.join(folder, "lib*.so*")):
            if HIDDEN.match(os.path.basename(path)) and os.path.realpath(path) not in found:
                found.append(os.path.realpath(path))
    return sorted(set(found))


def test_hidden(parent, python):
    hidden = system_library_files()
    binds = " && ".join("mount --bind /dev/null %s" % p for p in hidden) or "true"
    probe = "; ".join("test ! -s %s" % p for p in hidden) or "true"
    script = "%s && %s && exec %s %s %s %s" % (binds, probe, python, os.path.join(HERE, "smoke.py"), parent, MESH)
    out = subprocess.run(["unshare", "--mount", "--propagation", "private", "/bin/sh", "-c", script],
                         stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    names = sorted(set(re.sub(r"\.so.*", "", os.path.basename(p)) for p in hidden))
    last = out.stdout.strip().splitlines()[-1] if out.stdout.strip() else "(no output)"
    return check("hidden", out.returncode == 0, "%d files hidden (%s); %s" % (
        len(hidden), ", ".join(names) or "none installed", last))


def exported_names(path, dynamic=True):
    cmd = ["nm", "-D" if dynamic else "-g", "--defined-only", path]
    out = subprocess.run(cmd, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True).stdout
    return [line.split()[-1] for line in out.splitlines() if len(line.split()) >= 3 and line.split()[1] in "TW"]


def build_standins(workdir):
    """Stand-in libembree4.so.4, libtbb.so.12 and libosdCPU.so.3.6.0; returns their paths."""
    identifier = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")
    osd_archive = os.path.join(ROOT, "build", "package", "linux-x64", "osd", "lib", "libosdCPU.a")
    sets = {
        "libembree4.so.4": EMBREE_API + [n for p in glob.glob("/usr/lib/x86_64-linux-gnu/libembree*.so.*")
                                         for n in exported_names(p)],
        "libtbb.so.12": TBB_API + [n for p in glob.glob("/usr/lib/x86_64-linux-gnu/libtbb.so.*")
                                   for n in exported_names(p)],
        # Every function of the OpenSubdiv 3.6.0 core the library has inside:
        # the same versioned namespace as Blender's own copy.
        "libosdCPU.so.3.6.0": [n for n in (exported_names(osd_archive, dynamic=False)
                                           if os.path.exists(osd_archive) else []) if "OpenSubdiv" in n],
    }
    paths = []
    for soname, names in sets.items():
        names = sorted(set(n for n in names if identifier.match(n)))
        listing = os.path.join(workdir, soname + ".names")
        with open(listing, "w") as f:
            f.write("".join("X(%s)\n" % n for n in names))
        out = os.path.join(workdir, soname)
        subprocess.run(["cc", "-shared", "-fPIC", "-O0", "-w", "-o", out, "-Wl,-soname," + soname,
                        '-DSTANDIN_NAMES="%s"' % listing, os.path.join(HERE, "standin.c")], check=True)
        paths.append((out, len(names)))
    return paths


def blender_libraries():
    """{name: folder} with official Blender's own Embree 4, TBB and OpenSubdiv (and what they need),
    from the bpy wheels unpacked under build/bpy and from the wheel tools/package.py fetched."""
    folders = {}
    for lib_dir in sorted(glob.glob(os.path.join(ROOT, "build", "bpy", "*", "lib", "python*", "site-packages",
                                                 "bpy", "lib"))):
        folders["bpy %s" % lib_dir.split(os.sep + "bpy" + os.sep)[1].split(os.sep)[0]] = lib_dir
    import package  # tools/package.py
    wheel = package.blender_wheel()
    version = os.path.basename(wheel).split("-")[1]
    target = os.path.join(WORK, "blender-libs", version)
    if not os.path.isdir(target):
        with zipfile.ZipFile(wheel) as zf:
            for member in zf.namelist():
                if re.match(r"bpy/lib/lib(tbb|tbbmalloc|embree4|osdCPU|sycl|ur_loader)\.so", member):
                    with zf.open(member) as src, open(os.path.join(_mkdir(target), os.path.basename(member)),
                                                      "wb") as dst:
                        shutil.copyfileobj(src, dst)
    folders.setdefault("bpy %s wheel" % version, target)
    return folders


def _mkdir(path):
    os.makedirs(path, exist_ok=True)
    return path


def libc_imports(library):
    """The library's imports that are versioned symbols of the C library: a copy relocation in
    the program (stdout, ...) or an allocator it links may provide them, as for any library."""
    _defined, undefined = audit_elf.symbols(library)
    return {n for n, v, _b in undefined if v.startswith("GLIBC_")}


def bindings_of_library(log_prefix):
    """(target libraries, number of bindings) of every symbol lookup made for the library."""
    targets, count = {}, 0
    for path in glob.glob(log_prefix + "*"):
        for line in open(path, errors="replace"):
            m = re.search(r"binding file (\S+) \[\d+\] to (\S+) \[\d+\]: \S+ symbol `([^']+)'", line)
            if m and os.path.basename(m.group(1)) == LIBRARY:
                count += 1
                target = os.path.basename(m.group(2))
                targets.setdefault(target, []).append(m.group(3))
    return targets, count


def test_preloaded(name, parent, python, preload, library_path=None):
    workdir = tempfile.mkdtemp(prefix="bindings-", dir=WORK)
    log = os.path.join(workdir, "standin-calls.txt")
    env = dict(os.environ, LD_PRELOAD=":".join(preload), LD_DEBUG="bindings", LD_BIND_NOW="1",
               LD_DEBUG_OUTPUT=os.path.join(workdir, "ld"), SPIA_STANDIN_LOG=log)
    if library_path:
        env["LD_LIBRARY_PATH"] = library_path
    ok, last = smoke(python, parent, env=env)
    targets, count = bindings_of_library(os.path.join(workdir, "ld"))
    libc = libc_imports(os.path.join(parent, "subdiv_pia", "spia", LIBRARY))
    foreign = {t: [n for n in s if n not in libc] for t, s in targets.items() if t not in ALLOWED_TARGETS}
    foreign = {t: s for t, s in foreign.items() if s}
    called = open(log).read().split() if os.path.exists(log) else []
    detail = "%s; %d symbol lookups of the library, bound to %s" % (
        last, count, ", ".join(sorted(targets)) or "nothing")
    if foreign:
        detail += "; FOREIGN: " + "; ".join("%s <- %s" % (t, ", ".join(s[:4])) for t, s in foreign.items())
    if called:
        detail += "; stand-ins called: " + ", ".join(called[:5])
    return check(name, ok and count > 0 and not foreign and not called, detail)


def test_chroot(suite, parent):
    root = debian.chroot(suite + "-test", suite, dist.CHROOT_PACKAGES)
    present = [p for p in glob.glob(os.path.join(root, "usr", "lib", "**", "lib*.so*"), recursive=True)
               if HIDDEN.match(os.path.basename(p))]
    inner = "/opt/subdiv_pia-test"
    target = os.path.join(root, inner.lstrip("/"))
    shutil.rmtree(target, ignore_errors=True)
    shutil.copytree(parent, os.path.join(target, "package"))
    shutil.copy2(os.path.join(HERE, "smoke.py"), target)
    shutil.copy2(MESH, target)
    out = debian.in_chroot(root, "cat /etc/debian_version; python3 -c 'import sys, numpy; print(sys.version.split()[0], "
                                 "numpy.__version__)'; ldd --version | head -n 1; python3 %s/smoke.py %s/package %s/%s"
                           % (inner, inner, inner, os.path.basename(MESH)), check=False, capture=True)
    lines = out.stdout.strip().splitlines()
    facts = "Debian %s, Python %s, %s" % (lines[0] if lines else "?", lines[1] if len(lines) > 1 else "?",
                                          lines[2].split(")")[-1].strip() if len(lines) > 2 else "?")
    return check("chroot " + suite, out.returncode == 0 and not present,
                 "%s; %s%s" % (facts, lines[-1] if lines else "(no output)",
                               "; present: " + ", ".join(map(os.path.basename, present)) if present else ""))


def native_files(parent):
    folder = os.path.join(parent, "subdiv_pia")
    return sorted(os.path.relpath(os.path.join(d, n), folder) for d, _dirs, names in os.walk(folder)
                  for n in names if n.endswith((".so", ".dll", ".dylib", ".pyd")))


def manifest_platforms(parent):
    text = open(os.path.join(parent, "subdiv_pia", "blender_manifest.toml")).read()
    m = re.search(r"^platforms\s*=\s*\[([^\]]*)\]", text, re.M)
    return re.findall(r'"([^"]+)"', m.group(1)) if m else []


def test_windows(archive):
    """The Windows zip: its manifest, its DLL's imports and exports (its C
    tests ran under Wine when it was built: tools/package.py)."""
    import audit_pe
    parent = unpack(archive, "unpacked-windows")
    libraries = native_files(parent)
    check("windows manifest", manifest_platforms(parent) == ["windows-x64"] and libraries == ["spia/subdiv_pia.dll"],
          "platforms %s, libraries %s" % (manifest_platforms(parent), libraries))
    report, problems = audit_pe.audit(os.path.join(parent, "subdiv_pia", "spia", "subdiv_pia.dll"), HEADER)
    check("windows audit", not problems, "; ".join("%s %s" % kv for kv in report.items()) +
          ("; " + "; ".join(problems) if problems else ""))


def main(argv):
    if not argv or not all(a.endswith(".zip") for a in argv):
        print(__doc__)
        return 2
    os.makedirs(WORK, exist_ok=True)
    for other in argv[1:]:
        test_windows(os.path.abspath(other))
    archive = os.path.abspath(argv[0])
    parent = unpack(archive)
    library = os.path.join(parent, "subdiv_pia", "spia", LIBRARY)
    python = system_python()
    libraries = native_files(parent)
    check("linux manifest", manifest_platforms(parent) == ["linux-x64"] and libraries == ["spia/" + LIBRARY],
          "platforms %s, libraries %s" % (manifest_platforms(parent), libraries))

    report, problems = audit_elf.audit(library, HEADER, "2.28")  # official Blender runs on glibc 2.28
    check("audit", not problems, "; ".join("%s %s" % kv for kv in report.items()) +
          ("; " + "; ".join(problems) if problems else ""))
    ok, last = smoke(python, parent)
    check("host", ok, last)
    test_hidden(parent, python)
    standins = build_standins(tempfile.mkdtemp(prefix="standins-", dir=WORK))
    print("stand-ins: " + ", ".join("%s (%d names)" % (os.path.basename(p), n) for p, n in standins))
    test_preloaded("preloaded stand-ins", parent, python, [p for p, _n in standins])
    for name, lib_dir in blender_libraries().items():
        real = [os.path.join(lib_dir, n) for n in ("libtbb.so.12", "libembree4.so.4", "libosdCPU.so.3.6.0",
                                                   "libosdCPU.so.3.7.0")]
        real = [p for p in real if os.path.exists(p)]
        if real:
            test_preloaded("preloaded from %s (%s)" % (name, ", ".join(map(os.path.basename, real))),
                           parent, python, real, library_path=lib_dir)
        else:
            check("preloaded from %s" % name, False, "none of Blender's libraries found in %s" % lib_dir)
    host = debian.host_codename()
    for suite in ["bullseye", "trixie" if host == "bookworm" else "bookworm"]:
        test_chroot(suite, parent)

    failed = [r for r in results if not r[1]]
    print("\n| check | result | detail |\n|---|---|---|")
    for name, ok, detail in results:
        print("| %s | %s | %s |" % (name, "passed" if ok else "FAILED", detail.replace("|", "/")))
    print("\npackage tests: %d passed, %d failed" % (len(results) - len(failed), len(failed)))
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
