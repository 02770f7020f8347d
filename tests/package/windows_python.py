#!/usr/bin/env python3
# SPDX-License-Identifier: GPL-3.0-or-later
"""The Windows wheel in official Windows CPython, under Wine (`make
test-package`, after `make package`):

    python3 tests/package/windows_python.py

For each of CPython 3.13 with numpy 2.1.3, 3.11 with numpy 1.26.4 and 3.11
with numpy 2.1.3 (python.org's embeddable builds and numpy's win_amd64
wheels, from PyPI: tools/windows.py): PyPI's pip wheel, run by that
Python, installs dist/'s Windows wheel and that numpy into a folder the
embeddable's ._pth names (`pip install --target`, from the downloads only);
then client_check.py runs there, spia imported from that folder (drive
letter, backslashes), its library found beside it, and the cages it makes
of the inputs the Linux wheel was given must equal the Linux wheel's bit for
bit: the Linux wheel's client_check.py runs first, in a venv of this
machine's Python, and saves its inputs and cages
(build/package-test/windows/linux-cages.npz).

Prints a table and exits 1 if any run failed or could not run.
"""
import os
import subprocess
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(os.path.dirname(HERE))
sys.path.insert(0, os.path.join(ROOT, "tools"))
import package  # noqa: E402
import windows  # noqa: E402

WORK = os.path.join(ROOT, "build", "package-test", "windows")
RUNS = [("3.13", "numpy==2.1.3"), ("3.11", "numpy==1.26.4"), ("3.11", "numpy==2.1.3")]
CLIENT = os.path.join(HERE, "client_check.py")


def last_line(text):
    lines = [line for line in text.strip().splitlines() if line.strip()]
    return lines[-1] if lines else "(no output)"


def linux_reference():
    """The Linux wheel's client check in a venv of this Python, saving its
    cages; (ok, line, path of the cages)."""
    venv = os.path.join(WORK, "venv-linux")
    cages = os.path.join(WORK, "linux-cages.npz")
    if os.path.exists(cages):
        os.remove(cages)
    subprocess.run([sys.executable, "-m", "venv", "--clear", venv], check=True, stdout=subprocess.DEVNULL)
    python = os.path.join(venv, "bin", "python")
    out = subprocess.run([python, "-m", "pip", "install", "-q", "--disable-pip-version-check",
                          os.path.join(package.DIST, package.wheel_name("linux-x64")), "numpy"],
                         stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    if out.returncode != 0:
        return False, "pip install failed: %s" % out.stdout[-800:], cages
    out = subprocess.run([python, CLIENT, "--save-cages", cages], cwd=WORK, stdout=subprocess.PIPE,
                         stderr=subprocess.STDOUT, text=True)
    return out.returncode == 0 and os.path.exists(cages), last_line(out.stdout), cages


def windows_run(minor, numpy, reference):
    """(ok, how installed, detail) of the Windows wheel in that Python."""
    numpy_version = numpy.split("==")[1]
    env = windows.Environment("wheel-%s-numpy%s" % (minor, numpy_version), minor).prepare(fresh=True)
    wheel = os.path.join(package.DIST, package.wheel_name("windows-x64"))
    windows.wheel_file(numpy, minor)  # into the downloads, which pip reads below
    out = env.pip(["install", "-q", "--disable-pip-version-check", "--no-index", "--find-links",
                   windows.windows_path(windows.DOWNLOADS), "--target", windows.windows_path(env.site),
                   windows.windows_path(wheel), numpy])
    how = "pip %s --target (the ._pth's folder)" % windows.PIP.split("==")[1]
    if out.returncode != 0:
        return False, how, "pip install failed: %s" % out.stdout[-1200:]
    saved = os.path.join(WORK, "windows-%s-numpy%s-cages.npz" % (minor, numpy_version))
    args = [windows.windows_path(CLIENT), "--expect-prefix", windows.windows_path(env.site),
            "--save-cages", windows.windows_path(saved)]
    if reference:
        args += ["--compare-cages", windows.windows_path(reference)]
    out = env.run(args, cwd=WORK)
    line = last_line(out.stdout)
    if out.returncode != 0:
        line = "\n".join(out.stdout.strip().splitlines()[-30:])
    ok = out.returncode == 0 and "spia %s from Z:\\" % package.version() in line and "bit for bit" in line
    return ok, how, line


def main(argv):
    os.makedirs(WORK, exist_ok=True)
    rows = []
    t0 = time.time()
    ok, line, reference = linux_reference()
    rows.append(("Linux wheel, Python %d.%d (venv), reference cages" % sys.version_info[:2], "pip into a venv",
                 ok, line, time.time() - t0))
    for minor, numpy in RUNS:
        t0 = time.time()
        try:
            ok_run, how, detail = windows_run(minor, numpy, reference if ok else None)
        except (subprocess.SubprocessError, OSError, RuntimeError) as exc:
            ok_run, how, detail = False, "-", "could not run: %s" % exc
        name = "Windows wheel, %s, %s" % (windows.Environment("", minor).description(), numpy)
        rows.append((name, how, ok_run and ok, detail, time.time() - t0))
    print("\n| Python | installed with | result | minutes | detail |\n|---|---|---|---:|---|")
    for name, how, ok_row, detail, seconds in rows:
        print("| %s | %s | %s | %.1f | %s |" % (name, how, "passed" if ok_row else "FAILED", seconds / 60,
                                               detail.replace("|", "/").replace("\n", "<br>")))
    failed = [r for r in rows if not r[2]]
    print("\nWindows wheel tests: %d passed, %d failed" % (len(rows) - len(failed), len(failed)))
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
