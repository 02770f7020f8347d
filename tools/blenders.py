#!/usr/bin/env python3
# SPDX-License-Identifier: GPL-3.0-or-later
"""The Blenders this machine can test the add-on in, and the Blender test
suite (tests/blender) run in each of them against the package.

    python3 tools/blenders.py list
    python3 tools/blenders.py test EXTENSION.zip [--legacy LEGACY.zip] [-j 2] [--only NAME ...] [-- PYTEST ARGS]
    python3 tools/blenders.py window LEGACY.zip|ADDON_FOLDER

The Blenders:
- Debian's `blender` on the machine (3.4.1 on Debian 12, 4.3.2 on 13);
- Debian's `blender` of the other current release (13 on a Debian 12
  machine, else 12), in a chroot under build/chroots;
- official builds as Python modules: PyPI's `bpy` wheels, the newest patch
  of every release PyPI serves for a Python this machine has (bpy 4.2 to 5.0
  need Python 3.11, 5.1 and newer 3.13), each in a virtual environment
  under build/bpy/<release>, with the numpy that release's Blender bundles;
- official Windows builds under Wine (tools/windows.py): PyPI's win_amd64
  bpy wheels of 4.2 and 4.5 (LTS, Python 3.11) and 5.3 (3.13), each in
  python.org's embeddable Windows CPython under build/windows/bpy-<version>,
  tested with the Windows extension (the Linux one's name with
  windows_x64) on WINDOWS_SUITE, part of the suite.

Each suite runs with SUBDIV_PIA_PACKAGE=EXTENSION.zip and
SUBDIV_PIA_LEGACY_PACKAGE=LEGACY.zip: tests/blender/run.py installs the
extension (Blender 4.2 and newer: its installer installs the wheel inside)
or the legacy add-on (3.4 to 4.1) the way a user does, and the tests use
that copy.  Prints a
table of Blender (and how it was installed) against passed, failed,
skipped, and exits 1 if any suite failed or did not run.

`window` runs the window tests with the package's add-on (or the add-on in
a folder, such as build/addon), under Xvfb, in the Blenders that have a
window: Debian's two (the bpy module has none): tests/window/modal_fit.py
(the operator in Blender's window: modal, Esc cancels) and
tests/window/panel.py (the panel as Blender draws it, with screenshots under
build/window/<Blender>/).
"""
import argparse
import concurrent.futures
import glob
import os
import re
import shutil
import subprocess
import sys
import threading
import time
import xml.etree.ElementTree as ElementTree
import zipfile

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import debian  # noqa: E402
import windows  # noqa: E402

ROOT = debian.ROOT
BUILD = debian.BUILD
BPY = os.path.join(BUILD, "bpy")
RESULTS = os.path.join(BUILD, "blender-results")
FIRST_BPY = (4, 2)  # the first release with extensions; older bpy wheels are gone from PyPI
# Python minor version each bpy release needs.
PYTHON_OF_BPY = [((5, 1), "3.13"), ((4, 1), "3.11")]
RUN_PY = "tests/blender/run.py"
WINDOW_SCRIPTS = ("tests/window/modal_fit.py", "tests/window/panel.py")
WINDOW = os.path.join(BUILD, "window")
WINDOW_ADDON = os.path.join(WINDOW, "addon")
XVFB_RUN = 'xvfb-run -a -s "-screen 0 1600x900x24"'


def python_for(release):
    for first, python in PYTHON_OF_BPY:
        if release >= first:
            return python
    return None


def numpy_for(release):
    """The numpy the official Blender of that release bundles."""
    return "numpy>=2,<3" if release >= (5, 1) else "numpy>=1.26,<2"


def find_python(minor):
    """An interpreter of Python `minor` (e.g. '3.13') that runs, or None."""
    names = ["python" + minor]
    candidates = [shutil.which(n) for n in names] + ["/usr/bin/python" + minor, "/usr/local/bin/python" + minor]
    pyenv = os.environ.get("PYENV_ROOT", os.path.expanduser("~/.pyenv"))
    candidates += sorted(glob.glob(os.path.join(pyenv, "versions", minor + ".*", "bin", "python" + minor)), reverse=True)
    for path in candidates:
        if not path or not os.path.exists(path):
            continue
        try:
            out = subprocess.run([path, "-c", "import sys, venv; print('%d.%d' % sys.version_info[:2])"],
                                 stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True, timeout=30)
        except (OSError, subprocess.TimeoutExpired):
            continue
        if out.returncode == 0 and out.stdout.strip() == minor:
            return path
    return None


def served_releases(python):
    """{(major, minor): newest version} of the bpy wheels PyPI serves for `python`."""
    out = subprocess.run([python, "-m", "pip", "index", "versions", "bpy"], stdout=subprocess.PIPE,
                         stderr=subprocess.DEVNULL, text=True)
    m = re.search(r"Available versions: (.*)", out.stdout)
    newest = {}
    for v in (m.group(1).split(", ") if m else []):
        parts = v.strip().split(".")
        if len(parts) < 2 or not all(p.isdigit() for p in parts):
            continue  # pre-releases
        key = (int(parts[0]), int(parts[1]))
        if key >= FIRST_BPY and python_for(key) and (key not in newest or
                                                    tuple(map(int, parts)) > tuple(map(int, newest[key].split(".")))):
            newest[key] = v.strip()
    return newest


# What runs in the official Windows Blenders under Wine (the whole suite
# would take hours there): the package as installed, the window-free
# operator path, the script API and cli.py, scan fits and live updates, on
# meshes made in Blender.  Not there: the progress cli.py shows on a
# terminal (the tests make one with `pty`, which is POSIX's), and the tests
# that read tests/data's OBJ files (Blender's OBJ importer cannot map a
# file into memory under Wine 8, on any drive: "Cannot mmap file").
WINDOWS_SUITE = ["tests/blender/test_package.py", "tests/blender/test_operator.py",
                 "tests/blender/test_api_cli.py", "tests/blender/test_fit.py", "tests/blender/test_live.py"]
# Each cli.py test starts another Blender, which Wine makes slow: cli.py
# runs there on its own package (test_cli_uses_its_own_package),
# converts a .blend (test_cli_other_inputs[blend]), fails with its exit
# status and fits to a target (test_fit.py); its help, its PLY and STL
# readers and its OpenSubdiv versions run in the Linux Blenders only.
WINDOWS_DESELECT = " and ".join("not (%s)" % name for name in (
    "on_a_terminal", "test_cli_writes_blend", "test_cli_bad_opensubdiv_version", "test_bunny_scan_surface_fit",
    "test_scan_to_surface_distances_are_blenders", "test_paint_scan_writes_blenders_distances",
    "test_cli_help", "test_cli_opensubdiv_version", "test_cli_other_inputs[ply]", "test_cli_other_inputs[stl]"))


class Blender:
    def __init__(self, name, how, command, cwd=ROOT, root=None, prepare=None, windows=None):
        self.name, self.how, self.command, self.cwd, self.root, self.prepare = name, how, command, cwd, root, prepare
        self.windows = windows  # tools/windows.py's Environment: an official Windows build, under Wine


def debian_blender_version(command_prefix=()):
    try:
        out = subprocess.run(list(command_prefix) + ["blender", "--version"], stdout=subprocess.PIPE,
                             stderr=subprocess.DEVNULL, text=True, timeout=120)
    except (OSError, subprocess.TimeoutExpired):
        return None
    m = re.search(r"Blender (\d+\.\d+\.\d+)", out.stdout)
    return m.group(1) if m else None


def discover():
    """Every Blender this machine can test in, and notes on those it cannot."""
    blenders, notes = [], []
    host = debian.host_codename()
    if shutil.which("blender"):
        v = debian_blender_version()
        blenders.append(Blender("Blender %s" % v, "Debian %s package `blender`" % host,
                                ["blender", "-b", "--factory-startup", "--python-exit-code", "1", "--python", RUN_PY]))
    else:
        notes.append("no `blender` on PATH")
    other = "trixie" if host == "bookworm" else "bookworm"
    blenders.append(Blender("Debian %s's Blender" % other, "Debian %s package `blender`, in a chroot" % other,
                            ["blender", "-b", "--factory-startup", "--python-exit-code", "1", "--python", RUN_PY],
                            root=("%s-blender" % other, other)))
    for minor in sorted({p for _f, p in PYTHON_OF_BPY}):
        python = find_python(minor)
        if not python:
            notes.append("no Python %s here: bpy releases that need it are not tested" % minor)
            continue
        for release, version in sorted(served_releases(python).items()):
            if python_for(release) != minor:
                continue
            venv = os.path.join(BPY, "%d.%d" % release)
            blenders.append(Blender("Blender %s" % version, "PyPI `bpy==%s`, Python %s venv" % (version, minor),
                                    [os.path.join(venv, "bin", "python"), RUN_PY],
                                    prepare=(python, venv, version, numpy_for(release))))
    for version, minor, numpy in windows.BLENDERS:
        env = windows.blender(version, minor, numpy)
        blenders.append(Blender("Blender %s (Windows)" % version,
                                "PyPI `bpy==%s` win_amd64 wheel, %s, %s" % (version, env.description(), numpy),
                                env.command([RUN_PY]), windows=env))
    return blenders, notes


def prepare_venv(python, venv, version, numpy_requirement):
    stamp = os.path.join(venv, ".subdiv_pia-ready")
    want = "bpy==%s %s pytest" % (version, numpy_requirement)
    if os.path.exists(stamp) and open(stamp).read().strip() == want:
        return
    shutil.rmtree(venv, ignore_errors=True)
    debian.run([python, "-m", "venv", venv])
    debian.run([os.path.join(venv, "bin", "python"), "-m", "pip", "install", "-q", "--disable-pip-version-check",
                "--no-cache-dir", "bpy==" + version, numpy_requirement, "pytest"])
    with open(stamp, "w") as f:
        f.write(want + "\n")


def prepare_chroot(name, suite):
    # Debian's blender only recommends numpy, which the add-on needs.
    # Xvfb and Mesa's software OpenGL: Blender's window (`window`).
    path = debian.chroot(name, suite, ["blender", "python3-numpy", "python3-pytest", "xvfb", "xauth",
                                       "libgl1-mesa-dri"])
    return path


def enter_chroot(b):
    """Makes (or reuses) the chroot of Blender b, named by the version in it."""
    b.chroot_path = prepare_chroot(*b.root)
    v = debian_blender_version(["chroot", b.chroot_path])
    b.name = "Blender %s" % v if v else b.name


def counts(xml_paths):
    """passed, failed (failures and errors), skipped and expected failures over junit files."""
    total = {"passed": 0, "failed": 0, "skipped": 0, "xfailed": 0, "files": 0}
    for path in xml_paths:
        try:
            root = ElementTree.parse(path).getroot()
        except (OSError, ElementTree.ParseError):
            continue
        total["files"] += 1
        for case in root.iter("testcase"):
            if case.find("failure") is not None or case.find("error") is not None:
                total["failed"] += 1
            elif case.find("skipped") is not None:
                kind = case.find("skipped").get("type", "")
                total["xfailed" if "xfail" in kind else "skipped"] += 1
            else:
                total["passed"] += 1
    return total


def test_files(extra, blender=None):
    """The suite's files, one Blender process each (a process that ran them
    all grew to 8 GB in the bpy module); pytest arguments naming files or
    tests choose among them.  The Windows Blenders run WINDOWS_SUITE."""
    named = [a for a in extra if not a.startswith("-") and a.split("::")[0].endswith(".py")]
    options = [a for a in extra if a not in named]
    if blender is not None and blender.windows and not named:
        return list(WINDOWS_SUITE), options + ["-k", WINDOWS_DESELECT]
    files = named or sorted(os.path.relpath(p, ROOT) for p in glob.glob(os.path.join(ROOT, "tests", "blender",
                                                                                        "test_*.py")))
    return files, options


def clean_environment():
    """The caller's environment without what a Python version manager put in
    it: an interpreter first on PATH makes Debian's Blender take that
    Python's standard library instead of the system's."""
    env = {k: v for k, v in os.environ.items() if not k.startswith("PYENV")}
    env["PATH"] = os.pathsep.join(p for p in env.get("PATH", "").split(os.pathsep)
                                  if os.sep + ".pyenv" + os.sep + "versions" + os.sep not in p + os.sep)
    return env


def command_for(blender, package, selection, junit, legacy=None):
    """argv and environment running run.py on `selection` in `blender`."""
    if blender.root:
        inner = lambda path: "/src/" + os.path.relpath(path, ROOT)  # noqa: E731
        command = " ".join(blender.command + ["--", "--junitxml=" + inner(junit)] + selection)
        script = "cd /src && SUBDIV_PIA_PACKAGE=%s %s%s" % (
            inner(package), "SUBDIV_PIA_LEGACY_PACKAGE=%s " % inner(legacy) if legacy else "", command)
        argv = ["unshare", "--mount", "--propagation", "private", "/bin/sh", "-c",
                'mount -t proc proc "$R/proc" && mount --rbind /dev "$R/dev" && mount --bind "$S" "$R/src" && '
                'exec chroot "$R" /usr/bin/env -i PATH=/usr/sbin:/usr/bin:/sbin:/bin HOME=/root LANG=C.UTF-8 '
                '/bin/sh -c "$C"']
        os.makedirs(os.path.join(blender.chroot_path, "src"), exist_ok=True)
        return argv, dict(clean_environment(), R=blender.chroot_path, S=ROOT, C=script)
    if blender.windows:
        # Windows paths (drive Z: is /) for everything the suite reads.
        env = windows.wine_environment(dict(clean_environment(), SUBDIV_PIA_PACKAGE=windows.windows_path(package)))
        env.pop("SUBDIV_PIA_LEGACY_PACKAGE", None)
        env.pop("SUBDIV_PIA_ADDON_DIR", None)
        return blender.command + ["--", "--junitxml=" + windows.windows_path(junit)] + selection, env
    env = dict(clean_environment(), SUBDIV_PIA_PACKAGE=package)
    env.pop("SUBDIV_PIA_LEGACY_PACKAGE", None)
    if legacy:
        env["SUBDIV_PIA_LEGACY_PACKAGE"] = legacy
    env.pop("SUBDIV_PIA_ADDON_DIR", None)
    return blender.command + ["--", "--junitxml=" + junit] + selection, env


def run_suite(index, blender, package, extra, legacy=None):
    """The suite in one Blender, file by file; returns (counts, problems, seconds, log)."""
    if blender.windows:
        package = windows_package(package)
    os.makedirs(RESULTS, exist_ok=True)
    slug = re.sub(r"[^A-Za-z0-9.]+", "-", "%02d-%s-%s" % (index, blender.name, blender.how)).strip("-")
    log = os.path.join(RESULTS, slug + ".log")
    for old in glob.glob(os.path.join(RESULTS, slug + "-*.xml")):
        os.remove(old)
    files, options = test_files(extra, blender)
    problems, junits, t0 = [], [], time.time()
    with open(log, "w") as out:
        for k, name in enumerate(files):
            junit = os.path.join(RESULTS, "%s-%02d.xml" % (slug, k))
            argv, env = command_for(blender, package, [name] + options, junit, legacy)
            out.write("$ %s\n" % " ".join(argv))
            out.flush()
            if blender.windows:  # a pipe, not the log file, for Windows Python under Wine to start
                code = windows.run_piped(argv, lambda data: out.write(data.decode("utf-8", "replace")), env=env)
            else:
                code = subprocess.call(argv, cwd=ROOT, env=env, stdout=out, stderr=subprocess.STDOUT)
            junits.append(junit)
            if code != 0:
                problems.append("%s: exit %d" % (os.path.basename(name), code))
            if not os.path.exists(junit):
                problems.append("%s: no results" % os.path.basename(name))
    return counts(junits), problems, time.time() - t0, log


def windows_package(package):
    """The Windows extension beside the Linux one given."""
    return package.replace("-linux_x64.zip", "-windows_x64.zip")


def package_kind(blender, legacy):
    """Which package run.py installs in `blender` (named "Blender X.Y.Z")."""
    m = re.search(r"(\d+)\.(\d+)", blender.name)
    if legacy and m and (int(m.group(1)), int(m.group(2))) < (4, 2):
        return "legacy add-on"
    return "extension + wheel"


def test(package, jobs, only, extra, discard, legacy=None):
    """The suite in every Blender; with `discard`, each bpy venv (or Windows
    bpy environment) is removed once its suite has run and at most jobs + 1
    of them exist at a time (each is about 1 GB: all of them together can
    fill a small disk)."""
    blenders, notes = discover()
    if only:
        blenders = [b for b in blenders if any(o in b.name or o in b.how for o in only)]
    rows = {}
    slots = threading.BoundedSemaphore(jobs + 1)

    def discard_venv(b):
        if discard and (b.prepare or b.windows):
            shutil.rmtree(b.prepare[1] if b.prepare else b.windows.folder, ignore_errors=True)
            slots.release()

    def prepare(b):
        """Installs b's Blender (venv or chroot); None when it is ready."""
        try:
            if b.prepare:
                if discard:
                    slots.acquire()
                prepare_venv(*b.prepare)
            if b.windows:
                if discard:
                    slots.acquire()
                if not shutil.which("wine"):
                    raise RuntimeError("no `wine` here (Debian's wine and wine64)")
                if not os.path.isfile(windows_package(package)):
                    raise RuntimeError("no Windows extension %s" % windows_package(package))
                b.windows.prepare()
            if b.root:
                enter_chroot(b)
            return None
        except (subprocess.CalledProcessError, RuntimeError, OSError, StopIteration) as exc:
            return "could not be installed: %s" % exc

    def one(i, b):
        try:
            print("starting the suite in %s (%s)" % (b.name, b.how), flush=True)
            c, problems, seconds, log = run_suite(i, b, package, extra, legacy)
            print("finished %s (%s): %s%s" % (b.name, b.how, c, "; " + "; ".join(problems) if problems else ""),
                  flush=True)
            if problems or c["failed"]:
                print("---- last lines of %s ----\n%s" % (log, "".join(open(log, errors="replace").readlines()[-60:])),
                      flush=True)
            rows[id(b)] = (b, c, problems, seconds)
        finally:
            discard_venv(b)

    # Installing (mostly downloading) goes on in this thread while the
    # suites of the Blenders already installed run in the pool.
    with concurrent.futures.ThreadPoolExecutor(max_workers=max(1, jobs)) as pool:
        running = []
        for i, b in enumerate(blenders):
            problem = prepare(b)
            if problem:
                rows[id(b)] = (b, None, [problem], 0.0)
                discard_venv(b)
            else:
                running.append(pool.submit(one, i, b))
        for future in running:
            future.result()
    failed = 0
    print("\n| Blender | installed as | package | passed | failed | skipped | expected failures | minutes |\n"
          "|---|---|---|---:|---:|---:|---:|---:|")
    for b in blenders:
        b, c, problems, seconds = rows[id(b)]
        if c and c["files"]:
            print("| %s | %s | %s | %d | %d | %d | %d | %.1f |" % (
                b.name, b.how, package_kind(b, legacy), c["passed"], c["failed"], c["skipped"], c["xfailed"],
                seconds / 60))
        else:
            print("| %s | %s | %s | - | - | - | - | %s |" % (b.name, b.how, package_kind(b, legacy),
                                                              "; ".join(problems) or "no results"))
        failed += 1 if problems or not c or not c["files"] or c["failed"] else 0
    for note in notes:
        print("not tested: " + note)
    return 1 if failed or not rows else 0


def window(package):
    """The window tests with the package's add-on (a zip, or a folder holding
    subdiv_pia), in a window under Xvfb, in each Blender that has one; 0
    when they passed in all of them."""
    blenders, notes = discover()
    if os.path.isdir(package):
        addon_folder = package
    else:
        shutil.rmtree(WINDOW_ADDON, ignore_errors=True)
        os.makedirs(WINDOW_ADDON)
        with zipfile.ZipFile(package) as z:
            z.extractall(WINDOW_ADDON)
        addon_folder = WINDOW_ADDON
    results = []
    for b in blenders:
        if b.prepare or b.windows:
            continue  # the bpy module: no window
        if b.root:
            enter_chroot(b)
        inside = (lambda path: "/src/" + os.path.relpath(path, ROOT)) if b.root else (lambda path: path)  # noqa: E731
        pictures = os.path.join(WINDOW, re.sub(r"[^A-Za-z0-9.]+", "-", b.name))
        for script in WINDOW_SCRIPTS:
            command = "%s blender --factory-startup --enable-event-simulate --python %s%s" % (
                XVFB_RUN, script, " -- --screenshots %s" % inside(pictures) if script.endswith("panel.py") else "")
            print("%s in %s (%s)" % (script, b.name, b.how), flush=True)
            if b.root:
                code = debian.in_chroot(b.chroot_path, "cd /src && " + command, binds=[(ROOT, "/src")],
                                        env={"SUBDIV_PIA_ADDON_DIR": inside(addon_folder)}, check=False).returncode
            else:
                code = subprocess.call(command, shell=True, cwd=ROOT,
                                       env=dict(clean_environment(), SUBDIV_PIA_ADDON_DIR=addon_folder))
            results.append((b, script, code))
    for b, script, code in results:
        print("%s, %s (%s): %s" % (script, b.name, b.how, "passed" if code == 0 else "FAILED (exit %s)" % code))
    return 0 if results and all(code == 0 for _, _, code in results) else 1


def main(argv):
    parser = argparse.ArgumentParser(description="The Blender suite in every Blender this machine has.")
    sub = parser.add_subparsers(dest="command", required=True)
    sub.add_parser("list")
    t = sub.add_parser("test")
    t.add_argument("package", help="the extension zip (Blender 4.2 and newer)")
    t.add_argument("--legacy", help="the legacy add-on zip, for Blender 3.4 to 4.1")
    t.add_argument("-j", "--jobs", type=int, default=2)
    t.add_argument("--only", action="append", default=[], help="only Blenders whose name or origin contains this")
    t.add_argument("--discard-venvs", action="store_true",
                   help="remove each bpy venv after its suite (default: keep them for the next run)")
    w = sub.add_parser("window")
    w.add_argument("package", help="the legacy add-on zip, or a folder holding subdiv_pia (build/addon)")
    extra = argv[argv.index("--") + 1:] if "--" in argv else []
    args = parser.parse_args(argv[:argv.index("--")] if "--" in argv else argv)
    if args.command == "list":
        blenders, notes = discover()
        for b in blenders:
            print("%s: %s" % (b.name, b.how))
        for note in notes:
            print("not tested: " + note)
        return 0
    if args.command == "window":
        return window(os.path.abspath(args.package))
    return test(os.path.abspath(args.package), args.jobs, args.only, extra, args.discard_venvs,
                os.path.abspath(args.legacy) if args.legacy else None)


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
