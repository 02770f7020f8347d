# SPDX-License-Identifier: GPL-3.0-or-later
"""What the add-on says when its native library cannot be loaded: the
package for another platform, a glibc older than the library needs, a
missing dependency, a missing or bogus file (plain Python, no library
needed: the platform and the files are faked)."""
import importlib.util
import itertools
import os
import shutil
import sys

import pytest

from conftest import ADDON_DIR

MANIFEST = 'id = "subdiv_pia"\nversion = "0.2.0"\nplatforms = ["linux-x64"]\n'


COPIES = itertools.count()


@pytest.fixture
def native(tmp_path, monkeypatch):
    """A fresh copy of the binding (spia's modules) as a package of its own in
    tmp_path, with the manifest of a Linux x64 package and no library yet."""
    binding = os.path.join(ADDON_DIR, "subdiv_pia", "spia")
    for name in os.listdir(binding):
        if name.endswith(".py"):
            shutil.copy(os.path.join(binding, name), tmp_path / name)
    (tmp_path / "blender_manifest.toml").write_text(MANIFEST)
    name = "native_copy_%d" % next(COPIES)
    spec = importlib.util.spec_from_file_location(name, tmp_path / "__init__.py",
                                                  submodule_search_locations=[str(tmp_path)])
    module = importlib.util.module_from_spec(spec)
    monkeypatch.setitem(sys.modules, name, module)  # its modules import one another through it
    spec.loader.exec_module(module)
    monkeypatch.delenv("SUBDIV_PIA_LIBRARY", raising=False)
    yield module
    for key in [k for k in sys.modules if k.startswith(name + ".")]:
        del sys.modules[key]


def fake_platform(monkeypatch, native, system, machine):
    monkeypatch.setattr(native.sys, "platform", system)
    monkeypatch.setattr(native.platform, "machine", lambda: machine)


@pytest.mark.parametrize("system, machine, tag, library", (
    ("linux", "x86_64", "linux-x64", "libsubdiv_pia.so"),
    ("linux", "aarch64", "linux-arm64", "libsubdiv_pia.so"),
    ("win32", "AMD64", "windows-x64", "subdiv_pia.dll"),
    ("win32", "ARM64", "windows-arm64", "subdiv_pia.dll"),
    ("darwin", "arm64", "macos-arm64", "libsubdiv_pia.dylib"),
    ("darwin", "x86_64", "macos-x64", "libsubdiv_pia.dylib"),
))
def test_platform_tag_and_library_name(monkeypatch, native, system, machine, tag, library):
    fake_platform(monkeypatch, native, system, machine)
    assert native.platform_tag() == tag
    assert native.library_name() == library


@pytest.mark.parametrize("system, machine, tag, name", (
    ("win32", "AMD64", "windows-x64", "Windows x64"),
    ("darwin", "arm64", "macos-arm64", "macOS arm64"),
    ("linux", "aarch64", "linux-arm64", "Linux arm64"),
))
def test_package_for_another_platform_names_the_one_to_install(tmp_path, monkeypatch, native, system,
                                                               machine, tag, name):
    (tmp_path / "libsubdiv_pia.so").write_bytes(b"\x7fELF")  # the Linux library is there
    fake_platform(monkeypatch, native, system, machine)
    assert not native.available()
    head, *details = native.load_error().splitlines()
    assert head == ("This package is for Linux x64; this system is %s: install "
                    "subdiv_pia-0.2.0-legacy-%s.zip" % (name, tag.replace("-", "_")))
    # Windows, macOS: no library of theirs; Linux arm64: the x64 one does not load.
    assert len(details) == 1 and details[0].startswith("%s: " % (tmp_path / native.library_name()))
    with pytest.raises(native.PiaError) as error:
        native.version()
    assert error.value.code == "LIBRARY" and str(error.value).startswith(head)


def test_library_of_another_system_without_a_manifest(tmp_path, monkeypatch, native):
    """Outside an add-on (pip's wheel, or the extension's): the wheel is named."""
    os.remove(tmp_path / "blender_manifest.toml")
    (tmp_path / "subdiv_pia.dll").write_bytes(b"MZ")
    fake_platform(monkeypatch, native, "linux", "x86_64")
    head = native.load_error().splitlines()[0]
    assert head == ("This package has the native library for another system (subdiv_pia.dll); this "
                    "system is Linux x64: install the subdiv_pia wheel for Linux x64")


def test_library_missing_from_the_package(tmp_path, monkeypatch, native):
    fake_platform(monkeypatch, native, "linux", "x86_64")
    assert native.load_error().splitlines() == [
        "The native library (libsubdiv_pia.so) is missing from the package: install "
        "subdiv_pia-0.2.0-legacy-linux_x64.zip again",
        "%s: not found" % (tmp_path / "libsubdiv_pia.so")]


def _failing_load(monkeypatch, native, tmp_path, message):
    (tmp_path / "libsubdiv_pia.so").write_bytes(b"\x7fELF")

    def cdll(path, *args, **kwargs):
        raise OSError(message.format(path=path))
    monkeypatch.setattr(native.ctypes, "CDLL", cdll)


def test_glibc_too_old(tmp_path, monkeypatch, native):
    fake_platform(monkeypatch, native, "linux", "x86_64")
    _failing_load(monkeypatch, native, tmp_path,
                  "/lib/x86_64-linux-gnu/libc.so.6: version `GLIBC_2.32' not found (required by {path}); "
                  "/lib/x86_64-linux-gnu/libc.so.6: version `GLIBC_2.34' not found (required by {path})")
    monkeypatch.setattr(native.os, "confstr", lambda name: "glibc 2.28", raising=False)
    head, detail = native.load_error().splitlines()
    assert head == "The native library needs glibc 2.34 or newer; this system has glibc 2.28"
    assert "GLIBC_2.34" in detail and str(tmp_path) in detail
    assert native.glibc_version() == (2, 28)


def test_glibc_version_of_this_system(native):
    version = native.glibc_version()
    if hasattr(os, "confstr") and "glibc" in (os.confstr("CS_GNU_LIBC_VERSION") or ""):
        assert version is not None and version >= (2, 17)
    else:
        assert version is None


def test_missing_dependency_is_named(tmp_path, monkeypatch, native):
    fake_platform(monkeypatch, native, "linux", "x86_64")
    _failing_load(monkeypatch, native, tmp_path,
                  "libosdCPU.so.3.5.0: cannot open shared object file: No such file or directory")
    assert native.load_error().splitlines()[0] == \
        "The native library needs libosdCPU.so.3.5.0, which this system lacks"


def test_library_for_another_machine(tmp_path, monkeypatch, native):
    fake_platform(monkeypatch, native, "linux", "x86_64")
    _failing_load(monkeypatch, native, tmp_path, "{path}: wrong ELF class: ELFCLASS32")
    assert native.load_error().splitlines()[0] == \
        "The native library is not built for this system (Linux x64): install subdiv_pia-0.2.0-legacy-linux_x64.zip"


@pytest.mark.parametrize("kind", ("missing", "bogus"))
def test_library_named_by_the_environment_is_the_only_one_tried(tmp_path, monkeypatch, native, kind):
    (tmp_path / "libsubdiv_pia.so").write_bytes(b"\x7fELF")  # beside the binding: not tried
    named = tmp_path / "elsewhere.so"
    if kind == "bogus":
        named.write_text("not a library\n")
    monkeypatch.setenv("SUBDIV_PIA_LIBRARY", str(named))
    head, *details = native.load_error().splitlines()
    assert head == ("The library that SUBDIV_PIA_LIBRARY names is missing" if kind == "missing"
                    else "The library that SUBDIV_PIA_LIBRARY names is not a library for this system (%s)"
                    % native._platform_name(native.platform_tag()))
    assert len(details) == 1 and details[0].startswith(str(named) + ": ")


def test_the_real_library_loads_and_says_where_from():
    sys.path.insert(0, ADDON_DIR)
    from subdiv_pia import native
    assert native.available(), native.load_error()
    assert native.load_error() is None
    assert native.library_path() == os.path.join(os.path.abspath(ADDON_DIR), "subdiv_pia", "spia",
                                                 native.library_name())
