# SPDX-License-Identifier: GPL-3.0-or-later
"""The package's ELF audit (tests/package/audit_elf.py) tells a library that
could be shipped from one that could not: it is run here on small libraries
built for the purpose and on the development build, which links the
machine's OpenSubdiv and C++ runtime and so must fail it."""
import os
import subprocess
import sys

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
sys.path.insert(0, os.path.join(ROOT, "tests", "package"))
import audit_elf  # noqa: E402

HEADER = """
#define SPIA_API __attribute__((visibility("default")))
SPIA_API int spia_version(void);
SPIA_API const char *spia_result_name(int code);
"""
SOURCE = """
#include <stdlib.h>
#include <math.h>
__attribute__((visibility("default"))) int spia_version(void) { return getenv("X") ? 1 : (int)floor(0.5); }
__attribute__((visibility("default"))) const char *spia_result_name(int code) { return code ? "x" : "y"; }
%s
"""


def build(tmp_path, extra_source="", extra_flags=()):
    src = tmp_path / "lib.c"
    src.write_text(SOURCE % extra_source)
    header = tmp_path / "api.h"
    header.write_text(HEADER)
    out = tmp_path / "libsubdiv_pia.so"
    subprocess.run(["cc", "-shared", "-fPIC", "-fvisibility=hidden", "-o", str(out), str(src), "-lm"] +
                   list(extra_flags), check=True)
    return str(out), str(header)


def test_a_library_of_the_api_alone_passes(tmp_path):
    lib, header = build(tmp_path)
    report, problems = audit_elf.audit(lib, header, glibc_floor="2.31")
    assert problems == [], problems
    assert report["RUNPATH"] == "none"
    assert report["highest GLIBCXX/CXXABI"] == "none"


def test_an_exported_helper_fails(tmp_path):
    lib, header = build(tmp_path, '__attribute__((visibility("default"))) int helper(void) { return 1; }')
    _report, problems = audit_elf.audit(lib, header)
    assert any("beside the API" in p and "helper" in p for p in problems), problems


def test_a_missing_api_function_fails(tmp_path):
    lib, header = build(tmp_path)
    with open(header, "a") as f:
        f.write("SPIA_API int spia_missing(void);\n")
    _report, problems = audit_elf.audit(lib, header)
    assert any("does not export spia_missing" in p for p in problems), problems


def test_an_unversioned_import_fails(tmp_path):
    # A function the host process could provide (as Blender provides Embree's).
    lib, header = build(tmp_path, "void rtcNewDevice(void); void spia_x(void) { rtcNewDevice(); }")
    _report, problems = audit_elf.audit(lib, header)
    assert any("host process could provide" in p and "rtcNewDevice" in p for p in problems), problems


def test_a_foreign_runpath_fails(tmp_path):
    lib, header = build(tmp_path, extra_flags=["-Wl,-rpath,/opt/elsewhere", "-Wl,--enable-new-dtags"])
    _report, problems = audit_elf.audit(lib, header)
    assert any("RUNPATH /opt/elsewhere" in p for p in problems), problems


def test_a_glibc_floor_below_the_library_fails(tmp_path):
    lib, header = build(tmp_path)
    _report, problems = audit_elf.audit(lib, header, glibc_floor="2.0")
    assert any("above GLIBC_2.0" in p for p in problems), problems


def test_the_development_build_is_not_shippable():
    lib = os.path.join(os.environ.get("SUBDIV_PIA_ADDON_DIR", os.path.join(ROOT, "build", "addon")),
                       "subdiv_pia", "spia", "libsubdiv_pia.so")
    assert os.path.exists(lib), "make build first"
    report, problems = audit_elf.audit(lib, os.path.join(ROOT, "csrc", "include", "subdiv_pia.h"))
    # It links the system's C++ runtime; OpenSubdiv (3.6.0, static, as in
    # the package) is inside and none of its names is exported.
    assert any("libstdc++" in p for p in problems), problems
    assert "libosdCPU" not in report["NEEDED"]
    assert not any("OpenSubdiv" in p and p.startswith("exports") for p in problems), problems
