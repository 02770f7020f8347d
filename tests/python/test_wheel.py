# SPDX-License-Identifier: GPL-3.0-or-later
"""The wheel tools/package.py writes carries the whole binding: every module
of python/spia, byte for byte, and the library, each listed in RECORD with
its hash and size; unpacked, `import spia` from it loads the library and
interpolates.  (The wheels as shipped are checked by tests/package/dist.py
after `make package`; this writes one around the development build's
library, with stand-in licence texts, and needs neither.)"""
import base64
import hashlib
import os
import subprocess
import sys
import zipfile

from conftest import ADDON_DIR

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
sys.path.insert(0, os.path.join(ROOT, "tools"))
import package  # noqa: E402  (tools/package.py)

PKG_INFO = "Metadata-Version: 2.4\nName: subdiv_pia\nVersion: 0\nSummary: test\n\nThe description.\n"


def _wheel(tmp_path, monkeypatch):
    licence = tmp_path / "LICENSE.txt"
    licence.write_text("a licence text\n")
    monkeypatch.setattr(package, "DIST", str(tmp_path / "dist"))
    monkeypatch.setattr(package, "licence_files", lambda _folder: [("LICENSE", str(licence))])
    library = os.path.join(ADDON_DIR, "subdiv_pia", "spia", "libsubdiv_pia.so")
    return package.write_wheel("linux-x64", library, PKG_INFO)


def test_the_wheel_carries_every_module_of_the_binding(tmp_path, monkeypatch):
    path = _wheel(tmp_path, monkeypatch)
    binding = os.path.join(ROOT, "python", "spia")
    modules = sorted("spia/" + n for n in os.listdir(binding) if n.endswith(".py"))
    assert "spia/__init__.py" in modules
    with zipfile.ZipFile(path) as zf:
        data = {name: zf.read(name) for name in zf.namelist()}
    assert sorted(n for n in data if n.startswith("spia/")) == sorted(modules + ["spia/libsubdiv_pia.so"])
    for name in modules:
        with open(os.path.join(binding, name[len("spia/"):]), "rb") as f:
            assert data[name] == f.read(), name
    record = next(n for n in data if n.endswith(".dist-info/RECORD"))
    rows = [line.split(",") for line in data[record].decode().splitlines()]
    assert sorted(r[0] for r in rows) == sorted(data)
    for name, digest, size in rows:
        if name != record:
            expected = base64.urlsafe_b64encode(hashlib.sha256(data[name]).digest()).rstrip(b"=").decode()
            assert (digest, size) == ("sha256=" + expected, str(len(data[name]))), name


def test_the_unpacked_wheel_imports_and_interpolates(tmp_path, monkeypatch):
    path = _wheel(tmp_path, monkeypatch)
    target = tmp_path / "site"
    with zipfile.ZipFile(path) as zf:
        zf.extractall(target)
    code = ("import numpy as np, spia\n"
            "assert spia.__file__.startswith(%r), spia.__file__\n"
            "mesh = spia.Mesh.from_faces(np.array([[0,0,0],[1,0,0],[1,1,0],[0,1,0],[0,0,1],[1,0,1],[1,1,1],[0,1,1]],"
            " np.float32), [[0,3,2,1],[4,5,6,7],[0,1,5,4],[1,2,6,5],[2,3,7,6],[3,0,4,7]])\n"
            "cage, report = spia.interpolate(mesh)\n"
            "assert report.converged and spia.library_path().startswith(%r)\n"
            "print('ok', spia.version())\n") % (str(target), str(target))
    env = dict(os.environ, PYTHONPATH=str(target))
    env.pop("SUBDIV_PIA_LIBRARY", None)
    out = subprocess.run([sys.executable, "-c", code], cwd=str(tmp_path), env=env, capture_output=True, text=True)
    assert out.returncode == 0 and out.stdout.startswith("ok "), out.stdout + out.stderr
