#!/usr/bin/env python3
# SPDX-License-Identifier: GPL-3.0-or-later
"""Tests of the Python distribution and the Blender extensions as shipped
(`make test-package`, after `make package`):

    python3 tests/package/dist.py

(It runs itself again in build/venv-dist, whose packaging, twine and
auditwheel read what is shipped.)

1. files: the sdist, a wheel, an extension and a legacy zip per platform.
2. twine: `twine check --strict` on every wheel and the sdist.
3. auditwheel: `auditwheel show` finds the Linux wheel consistent with
   manylinux_2_17_x86_64.
4. wheels: each holds the binding (every module of python/spia, the same
   bytes as the legacy zip's; the sdist has them too), its platform's
   library (the same bytes as the library built, audited and tested for
   that platform, and as the legacy zip's) and its .dist-info: RECORD's hashes and sizes, WHEEL's tag
   as the file name says, METADATA valid (packaging's parser), its version
   the add-on's, numpy required, a licence expression naming everything
   inside and a License-File line for each text.
5. extensions: each is the pure Python add-on and its platform's wheel
   under ./wheels/, unchanged, listed in its manifest; no native file
   elsewhere and no binding outside the wheel; Blender's validator accepts
   it in strict mode; dist/repo/ lists the four and nothing else.
6. sdist: built by the backend (scikit-build-core) in a clean virtual
   environment, against an installed OpenSubdiv 3.6.0 (a prefix found
   through CMAKE_PREFIX_PATH), it installs and passes client_check.py.
7. venvs: the Linux wheel installed with pip into clean virtual
   environments of Python 3.9 to 3.13 with numpy 1.x and 2.x (every pair
   numpy publishes wheels for) passes client_check.py there.
8. Debian 11: the same in a venv of the bullseye chroot's Python 3.9 with
   Debian's numpy 1.19.
9. trimesh: trimesh_client.py in a venv with the wheel and trimesh.

Prints a table of the checks and exits 1 if any failed.
"""
import concurrent.futures
import glob
import hashlib
import base64
import json
import os
import re
import shutil
import subprocess
import sys
import tarfile
import time
import zipfile

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(os.path.dirname(HERE))
sys.path.insert(0, os.path.join(ROOT, "tools"))
import debian  # noqa: E402
import package  # noqa: E402

WORK = os.path.join(ROOT, "build", "package-test", "dist")
DIST = package.DIST
PYENV = os.path.expanduser("~/.pyenv/versions")
# (Python, numpy requirement): numpy 1.x has no wheels for Python 3.13.
MATRIX = [("3.9", "numpy<2"), ("3.9", "numpy>=2"), ("3.10", "numpy<2"), ("3.10", "numpy>=2"),
          ("3.11", "numpy<2"), ("3.11", "numpy>=2"), ("3.12", "numpy<2"), ("3.12", "numpy>=2"),
          ("3.13", "numpy>=2")]
# The clean Debian 11 and 12/13 chroots (tests/package/run.py uses the same).
CHROOT_PACKAGES = ["python3-numpy", "python3-pip", "python3-venv"]
TRIMESH_MESH = os.path.join(ROOT, "tests", "data", "armadillo.obj")

results = []


def check(name, ok, detail):
    results.append((name, bool(ok), detail))
    print("%s %s: %s" % ("PASS" if ok else "FAIL", name, detail), flush=True)
    return ok


def run(argv, **kw):
    return subprocess.run(argv, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, **kw)


def last_line(out):
    lines = [l for l in out.strip().splitlines() if l.strip() and not l.startswith("WARNING: Location")]
    return lines[-1] if lines else "(no output)"


def files():
    wanted = {"sdist": os.path.join(DIST, package.sdist_name())}
    for p in package.PLATFORMS:
        wanted["wheel " + p] = os.path.join(DIST, package.wheel_name(p))
        wanted["extension " + p] = os.path.join(DIST, package.extension_name(p))
        wanted["legacy " + p] = os.path.join(DIST, package.legacy_name(p))
    missing = [k for k, v in wanted.items() if not os.path.isfile(v)]
    check("files", not missing, "; ".join("%s %s (%d B)" % (k, os.path.basename(v), os.path.getsize(v))
                                          for k, v in wanted.items() if k not in missing) +
          ("; MISSING: " + ", ".join(missing) if missing else ""))
    return not missing


def twine():
    targets = [os.path.join(DIST, package.wheel_name(p)) for p in package.PLATFORMS]
    targets.append(os.path.join(DIST, package.sdist_name()))
    out = run([package.dist_python(), "-m", "twine", "check", "--strict"] + targets)
    passed = len(re.findall(r"PASSED", out.stdout))
    check("twine check --strict", out.returncode == 0 and passed == len(targets),
          "%d of %d passed%s" % (passed, len(targets), "" if out.returncode == 0 else ": " + out.stdout[-400:]))


def auditwheel():
    wheel = os.path.join(DIST, package.wheel_name("linux-x64"))
    out = run([package.dist_python(), "-m", "auditwheel", "show", wheel])
    text = " ".join(out.stdout.split())
    tag = re.search(r'is consistent with the following platform tag: "([^"]+)"', text)
    check("auditwheel show", out.returncode == 0 and tag and tag.group(1) == "manylinux_2_17_x86_64",
          "consistent with %s" % (tag.group(1) if tag else "nothing: " + text[-300:]))


def record_hash(data):
    return "sha256=" + base64.urlsafe_b64encode(hashlib.sha256(data).digest()).rstrip(b"=").decode()


def zip_native_files(names):
    return [n for n in names if n.endswith((".so", ".dll", ".dylib", ".pyd"))]


def wheel_contents(platform):
    """Checks one wheel; returns its bytes."""
    from packaging.metadata import Metadata
    from packaging.licenses import canonicalize_license_expression
    path = os.path.join(DIST, package.wheel_name(platform))
    library_name = package.LIBRARY_NAMES[platform]
    dist_info = "subdiv_pia-%s.dist-info" % package.version()
    problems = []
    with zipfile.ZipFile(path) as zf:
        names = zf.namelist()
        data = {n: zf.read(n) for n in names}
    licences = sorted(n for n in names if n.startswith(dist_info + "/licenses/"))
    binding = package.binding_files()
    expected = sorted([name for name, _path in binding] + ["spia/" + library_name, dist_info + "/METADATA",
                                                           dist_info + "/WHEEL", dist_info + "/RECORD"] + licences)
    if sorted(names) != expected or len(licences) < 4 or "spia/__init__.py" not in dict(binding):
        problems.append("contents %s" % names)
    for name, source in binding:
        if data.get(name) != open(source, "rb").read():
            problems.append("%s is not %s" % (name, os.path.relpath(source, ROOT)))
    built = os.path.join(package.BUILD, "package", platform, library_name)
    if data.get("spia/" + library_name) != open(built, "rb").read():
        problems.append("the library is not %s" % built)
    with zipfile.ZipFile(os.path.join(DIST, package.legacy_name(platform))) as zf:
        legacy = set(zf.namelist())
        if data.get("spia/" + library_name) != zf.read("subdiv_pia/spia/" + library_name):
            problems.append("the legacy zip holds another library")
        missing = sorted(set("subdiv_pia/" + n for n in addon_files()) - legacy)
        if missing:
            problems.append("the legacy zip lacks %s" % missing)
        for name, source in binding:
            if "subdiv_pia/" + name not in legacy or zf.read("subdiv_pia/" + name) != open(source, "rb").read():
                problems.append("the legacy zip's %s is not %s" % (name, os.path.relpath(source, ROOT)))
    record = [line.split(",") for line in data[dist_info + "/RECORD"].decode().splitlines()]
    listed = {r[0]: r for r in record}
    if sorted(listed) != sorted(names):
        problems.append("RECORD lists %s" % sorted(listed))
    for name in names:
        if name.endswith("/RECORD"):
            continue
        r = listed.get(name)
        if not r or r[1] != record_hash(data[name]) or r[2] != str(len(data[name])):
            problems.append("RECORD wrong for %s" % name)
    wheel = data[dist_info + "/WHEEL"].decode()
    tag = re.search(r"^Tag: (\S+)$", wheel, re.M)
    if not tag or tag.group(1) != "py3-none-" + package.WHEEL_TAGS[platform] or \
            not os.path.basename(path).endswith("-%s.whl" % tag.group(1)) or "Root-Is-Purelib: false" not in wheel:
        problems.append("WHEEL %r" % wheel)
    meta = Metadata.from_email(data[dist_info + "/METADATA"], validate=True)
    if str(meta.name) != "subdiv_pia" or str(meta.version) != package.version():
        problems.append("name/version %s %s" % (meta.name, meta.version))
    if [str(r) for r in meta.requires_dist or []] != ["numpy>=1.19"] or str(meta.requires_python) != ">=3.9":
        problems.append("requires %s, python %s" % (meta.requires_dist, meta.requires_python))
    expression = str(meta.license_expression)
    if canonicalize_license_expression(expression) != expression or "Pixar" not in expression or \
            "GPL-3.0-or-later" not in expression:
        problems.append("licence expression %r" % expression)
    if sorted(dist_info + "/licenses/" + f for f in meta.license_files or []) != licences:
        problems.append("License-File %s, texts %s" % (meta.license_files, licences))
    if any(len(data[n]) < 300 for n in licences):
        problems.append("a licence text is almost empty")
    check("wheel " + platform, not problems, "%s (%d B): %s; %s; %d licence texts" % (
        os.path.basename(path), os.path.getsize(path), tag.group(1) if tag else "?", expression, len(licences))
        + ("; " + "; ".join(problems) if problems else ""))
    return open(path, "rb").read()


def addon_files():
    """The add-on's files as a package holds them (relative to its folder):
    its modules and its built-in presets (addon/presets/)."""
    folder = os.path.join(ROOT, "addon")
    return [os.path.relpath(os.path.join(d, n), folder).replace(os.sep, "/")
            for d, dirs, files in os.walk(folder) if "__pycache__" not in d
            for n in files if n.endswith(".py")]


def extension(platform, wheel_bytes):
    path = os.path.join(DIST, package.extension_name(platform))
    problems = []
    with zipfile.ZipFile(path) as zf:
        names = zf.namelist()
        manifest = zf.read("blender_manifest.toml").decode()
        wheels = sorted(n for n in names if n.startswith("wheels/"))
        inside = {n: zf.read(n) for n in wheels}
    try:
        import tomllib
        parsed = tomllib.loads(manifest)
    except ImportError:  # Python 3.10: the two lists, read by hand
        parsed = {k: re.findall(r'"([^"]+)"', v) for k, v in
                  re.findall(r"^(platforms|wheels)\s*=\s*\[([^\]]*)\]", manifest, re.M | re.S)}
        parsed["build"] = {}
    generated = parsed.get("build", {}).get("generated", {})
    platforms = generated.get("platforms", parsed.get("platforms"))
    listed = generated.get("wheels", parsed.get("wheels"))
    wheel = package.wheel_name(platform)
    if platforms != [platform]:
        problems.append("platforms %s" % platforms)
    if listed != ["./wheels/" + wheel] or wheels != ["wheels/" + wheel]:
        problems.append("wheels listed %s, inside %s" % (listed, wheels))
    if inside.get("wheels/" + wheel) != wheel_bytes:
        problems.append("the wheel inside is not dist/%s" % wheel)
    if zip_native_files(names):
        problems.append("native files %s" % zip_native_files(names))
    if any(n.startswith("spia/") or "/spia/" in n for n in names):
        problems.append("a binding outside the wheel")
    if "__init__.py" not in names or "native.py" not in names:
        problems.append("not the add-on: %s" % names)
    missing = sorted(set(addon_files()) - set(names))
    if missing:  # the add-on's modules, and its built-in presets
        problems.append("the add-on's %s missing" % missing)
    python, tool, tags = package.blender_extension_tool()
    out = run([python, tool, "validate", "--valid-tags=" + tags, path])
    if out.returncode != 0:
        problems.append("validator: %s" % last_line(out.stdout))
    check("extension " + platform, not problems, "%s (%d B): %d files, %s; validator (strict): %s" % (
        os.path.basename(path), os.path.getsize(path), len(names), ", ".join(wheels),
        last_line(out.stdout)) + ("; " + "; ".join(problems) if problems else ""))


def repository():
    with open(os.path.join(DIST, "repo", "index.json")) as f:
        index = json.load(f)
    entries = sorted((e.get("archive_url", "").lstrip("./"), tuple(e.get("platforms", []))) for e in index["data"])
    expected = sorted((package.extension_name(p), (p,)) for p in package.PLATFORMS)
    check("repository", entries == expected, "dist/repo/index.json lists %s" % (
        ", ".join("%s (%s)" % (a, ", ".join(p)) for a, p in entries)))


def venv(python, folder):
    shutil.rmtree(folder, ignore_errors=True)
    subprocess.run([python, "-m", "venv", folder], check=True, stdout=subprocess.DEVNULL)
    return os.path.join(folder, "bin", "python")


def pip(python, args, env=None):
    return run([python, "-m", "pip", "install", "-q", "--disable-pip-version-check"] + args,
               env=dict(env or os.environ, PIP_NO_WARN_SCRIPT_LOCATION="1"))


def client_check(python, cwd):
    out = run([python, os.path.join(HERE, "client_check.py")], cwd=cwd)
    return out.returncode == 0, last_line(out.stdout)


def opensubdiv_prefix():
    """OpenSubdiv 3.6.0 as an installed prefix (headers and the static
    archive, from the build every other build links)."""
    src, archive = package.host_opensubdiv(sys.stderr)
    prefix = os.path.join(package.BUILD, "osd", "host-prefix")
    shutil.rmtree(prefix, ignore_errors=True)
    os.makedirs(os.path.join(prefix, "lib"))
    shutil.copy2(archive, os.path.join(prefix, "lib"))
    for folder, _dirs, names in os.walk(os.path.join(src, "opensubdiv")):
        for name in names:
            if name.endswith(".h"):
                target = os.path.join(prefix, "include", os.path.relpath(os.path.join(folder, name), src))
                os.makedirs(os.path.dirname(target), exist_ok=True)
                shutil.copy2(os.path.join(folder, name), target)
    return prefix


def sdist():
    path = os.path.join(DIST, package.sdist_name())
    with tarfile.open(path) as tar:
        names = tar.getnames()
    top = "subdiv_pia-%s/" % package.version()
    stray = [n for n in names if n.startswith(tuple(top + d for d in ("tests", "bench", "build", "dist", "tools")))]
    missing = [name for name, _path in package.binding_files() if top + "python/" + name not in names]
    prefix = opensubdiv_prefix()
    python = venv(sys.executable, os.path.join(WORK, "venv-sdist"))
    t0 = time.time()
    out = pip(python, [path], env=dict(os.environ, CMAKE_PREFIX_PATH=prefix))
    seconds = time.time() - t0
    if out.returncode != 0:
        return check("sdist", False, "pip install failed: %s" % out.stdout[-1500:])
    ok, line = client_check(python, WORK)
    check("sdist", ok and not stray and not missing and top + "PKG-INFO" in names,
          "%d files; built with scikit-build-core against %s and installed in %.0f s; %s%s%s" % (
              len(names), prefix, seconds, line, "; stray: %s" % stray[:5] if stray else "",
              "; binding modules missing: %s" % missing if missing else ""))


def one_venv(minor, numpy):
    found = sorted(glob.glob(os.path.join(PYENV, minor + ".*", "bin", "python3")))
    name = "venv %s %s" % (minor, numpy)
    if not found:
        return name, False, "no Python %s under %s" % (minor, PYENV)
    python = venv(found[-1], os.path.join(WORK, "venv-%s-%s" % (minor, "np1" if "<2" in numpy else "np2")))
    out = pip(python, [os.path.join(DIST, package.wheel_name("linux-x64")), numpy])
    if out.returncode != 0:
        return name, False, "pip install failed: %s" % out.stdout[-800:]
    ok, line = client_check(python, WORK)
    return name, ok, line


def venvs(jobs=2):
    with concurrent.futures.ThreadPoolExecutor(max_workers=jobs) as pool:
        for name, ok, line in pool.map(lambda m: one_venv(*m), MATRIX):
            check(name, ok, line)


def debian_11():
    root = debian.chroot("bullseye-test", "bullseye", CHROOT_PACKAGES)
    inner = "/opt/subdiv_pia-dist"
    target = os.path.join(root, inner.lstrip("/"))
    shutil.rmtree(target, ignore_errors=True)
    os.makedirs(target)
    wheel = package.wheel_name("linux-x64")
    shutil.copy2(os.path.join(DIST, wheel), target)
    shutil.copy2(os.path.join(HERE, "client_check.py"), target)
    shutil.copy2(os.path.join(ROOT, "tests", "python", "spheres.py"), target)
    script = ("cd {d} && python3 -m venv --system-site-packages venv && "
              "venv/bin/pip install -q --no-index --disable-pip-version-check {d}/{w} && "
              "cat /etc/debian_version && venv/bin/pip --version && venv/bin/python client_check.py"
              ).format(d=inner, w=wheel)
    out = debian.in_chroot(root, script, check=False, capture=True)
    lines = out.stdout.strip().splitlines()
    check("Debian 11 venv", out.returncode == 0, "Debian %s, %s; %s" % (
        lines[0] if lines else "?", " ".join(lines[1].split()[:2]) if len(lines) > 1 else "?",
        lines[-1] if lines else "(no output)"))


def trimesh():
    pythons = sorted(glob.glob(os.path.join(PYENV, "3.11.*", "bin", "python3"))) or [sys.executable]
    python = venv(pythons[-1], os.path.join(WORK, "venv-trimesh"))
    out = pip(python, [os.path.join(DIST, package.wheel_name("linux-x64")), "trimesh"])
    if out.returncode != 0:
        return check("trimesh client", False, "pip install failed: %s" % out.stdout[-800:])
    cage = os.path.join(WORK, "armadillo_cage.obj")
    out = run([python, os.path.join(HERE, "trimesh_client.py"), TRIMESH_MESH, cage], cwd=WORK)
    check("trimesh client", out.returncode == 0 and os.path.isfile(cage), last_line(out.stdout))


def main(argv):
    python = package.dist_python()
    if os.path.realpath(sys.prefix) != os.path.realpath(package.DIST_VENV):
        os.execv(python, [python, os.path.abspath(__file__)] + argv)
    os.makedirs(WORK, exist_ok=True)
    if files():
        twine()
        auditwheel()
        for platform in package.PLATFORMS:
            extension(platform, wheel_contents(platform))
        repository()
        sdist()
        venvs()
        debian_11()
        trimesh()
    failed = [r for r in results if not r[1]]
    print("\n| check | result | detail |\n|---|---|---|")
    for name, ok, detail in results:
        print("| %s | %s | %s |" % (name, "passed" if ok else "FAILED", detail.replace("|", "/")))
    print("\ndistribution tests: %d passed, %d failed" % (len(results) - len(failed), len(failed)))
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
