#!/usr/bin/env python3
# SPDX-License-Identifier: GPL-3.0-or-later
"""ELF audit of the shipped library: what it needs from the system and what
it shows a host process.

    audit_elf.py LIBRARY [--header csrc/include/subdiv_pia.h] [--glibc 2.31]

Prints NEEDED, RUNPATH, the highest GLIBC and GLIBCXX versions it asks for
and the symbols it exports and imports, and exits 1 when anything is
outside what the package promises:

- NEEDED only the C library's own parts (libc, libm, libpthread, libdl, rt),
  libgcc_s and the loader; libgomp.so.1 only when it is shipped beside the
  library and found there through RUNPATH $ORIGIN;
- RUNPATH absent or $ORIGIN;
- no symbol version above GLIBC_<floor>, none of libstdc++ (GLIBCXX_,
  CXXABI_): the C++ runtime is inside;
- exported: exactly the functions the header declares with SPIA_API;
- imported: only versioned symbols of those libraries, so that no copy of
  OpenSubdiv, Embree, TBB or the C++ runtime in the host process (Blender
  loads all of them) can be bound to a call of the library.

Needs binutils' readelf.
"""
import argparse
import os
import re
import subprocess
import sys

ALLOWED_NEEDED = {"libc.so.6", "libm.so.6", "libpthread.so.0", "libdl.so.2", "librt.so.1", "libgcc_s.so.1",
                  "ld-linux-x86-64.so.2"}
# Weak references every GCC-built shared object carries (crtbegin's):
# unversioned only where the object asks nothing else of the C library.
ALLOWED_UNVERSIONED_WEAK = {"__gmon_start__", "_ITM_deregisterTMCloneTable", "_ITM_registerTMCloneTable",
                            "__cxa_finalize"}
ALLOWED_IMPORT_VERSIONS = re.compile(r"^(GLIBC_[0-9.]+|GCC_[0-9.]+)$")


def readelf(*args):
    return subprocess.run(["readelf", "-W"] + list(args), check=True, stdout=subprocess.PIPE, text=True).stdout


def version_key(v):
    return tuple(int(x) for x in re.findall(r"\d+", v))


def dynamic(path):
    out = readelf("-d", path)
    needed = re.findall(r"\(NEEDED\)\s+Shared library: \[([^\]]+)\]", out)
    runpath = re.findall(r"\((?:RUNPATH|RPATH)\)\s+Library r(?:un)?path: \[([^\]]*)\]", out)
    return needed, runpath


def symbols(path):
    """(defined global symbols, undefined symbols) as lists of (name, version, bind)."""
    defined, undefined = [], []
    for line in readelf("--dyn-syms", path).splitlines():
        m = re.match(r"\s*\d+:\s+[0-9a-f]+\s+\d+\s+(\w+)\s+(\w+)\s+(\w+)\s+(\w+)\s+(\S+)", line)
        if not m:
            continue
        kind, bind, _vis, ndx, name = m.groups()
        if kind in ("SECTION", "FILE") or name == "":
            continue
        name, _, ver = name.partition("@")
        ver = ver.lstrip("@")
        ver = re.sub(r"\s*\(\d+\)$", "", ver)
        if ndx == "UND":
            undefined.append((name, ver, bind))
        elif bind in ("GLOBAL", "WEAK", "GNU_UNIQUE"):
            defined.append((name, ver, bind))
    return defined, undefined


def required_versions(path):
    """Every version the library needs, from .gnu.version_r: {library: [versions]}."""
    out = readelf("-V", path)
    result, current = {}, None
    for line in out.splitlines():
        m = re.search(r"File: (\S+)\s+Cnt:", line)
        if m:
            current = m.group(1)
            result.setdefault(current, [])
            continue
        m = re.search(r"Name: (\S+)\s+Flags:", line)
        if m and current:
            result[current].append(m.group(1))
    return result


def export_problems(exported, header=None):
    """What is wrong with a library's exported names: anything beside spia_*,
    and (given the header) names it declares but the library lacks, or the
    other way round."""
    problems = []
    foreign = [n for n in exported if not n.startswith("spia_")]
    if foreign:
        problems.append("exports %d names beside the API, e.g. %s" % (len(foreign), ", ".join(foreign[:5])))
    if header:
        api = header_api(header)
        missing = sorted(api - set(exported))
        extra = sorted(set(n for n in exported if n.startswith("spia_")) - api)
        if missing:
            problems.append("does not export %s (declared in %s)" % (", ".join(missing), os.path.basename(header)))
        if extra:
            problems.append("exports %s, which the header does not declare" % ", ".join(extra))
    return problems


def header_api(header):
    text = open(header).read()
    return set(re.findall(r"SPIA_API\s+[^;{(]*?\b(spia_\w+)\s*\(", text))


def audit(path, header=None, glibc_floor="2.31"):
    problems = []
    needed, runpath = dynamic(path)
    defined, undefined = symbols(path)
    versions = required_versions(path)
    here = os.path.dirname(os.path.abspath(path))

    for lib in needed:
        if lib in ALLOWED_NEEDED:
            continue
        if lib == "libgomp.so.1" and runpath == ["$ORIGIN"] and os.path.exists(os.path.join(here, lib)):
            continue
        problems.append("NEEDED %s is not allowed" % lib)
    for rp in runpath:
        if rp != "$ORIGIN":
            problems.append("RUNPATH %s is not allowed (only $ORIGIN)" % rp)

    all_versions = [v for vs in versions.values() for v in vs]
    glibc = sorted((v for v in all_versions if v.startswith("GLIBC_") and v[6:7].isdigit()), key=version_key)
    glibcxx = sorted((v for v in all_versions if v.startswith(("GLIBCXX_", "CXXABI_"))), key=version_key)
    if glibc and version_key(glibc[-1]) > version_key(glibc_floor):
        problems.append("needs %s, above GLIBC_%s" % (glibc[-1], glibc_floor))
    if glibcxx:
        problems.append("needs the system's C++ runtime: %s" % ", ".join(glibcxx))

    exported = sorted(name for name, _v, _b in defined)
    problems += export_problems(exported, header)

    unbound = [(n, v, b) for n, v, b in undefined
               if not (ALLOWED_IMPORT_VERSIONS.match(v) or (not v and b == "WEAK" and n in ALLOWED_UNVERSIONED_WEAK))]
    if unbound:
        problems.append("imports %d symbols a host process could provide: %s" % (
            len(unbound), ", ".join("%s%s" % (n, "@" + v if v else "") for n, v, _b in unbound[:8])))

    report = {
        "NEEDED": ", ".join(needed) or "none",
        "RUNPATH": ", ".join(runpath) or "none",
        "highest GLIBC": glibc[-1] if glibc else "none",
        "highest GLIBCXX/CXXABI": glibcxx[-1] if glibcxx else "none",
        "exported": "%d symbols, %d outside spia_*" % (len(exported),
                                                      sum(not n.startswith("spia_") for n in exported)),
        "imported": "%d symbols, %d unversioned or from other libraries" % (len(undefined), len(unbound)),
        "size": "%.2f MB" % (os.path.getsize(path) / 1e6),
    }
    return report, problems


def main(argv):
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("library")
    parser.add_argument("--header")
    parser.add_argument("--glibc", default="2.31", help="the highest GLIBC version allowed")
    args = parser.parse_args(argv)
    report, problems = audit(args.library, args.header, args.glibc)
    print("ELF audit of %s" % args.library)
    print("| check | found |\n|---|---|")
    for key, value in report.items():
        print("| %s | %s |" % (key, value))
    for problem in problems:
        print("FAIL: " + problem)
    print("audit: %s" % ("passed" if not problems else "%d problem%s" % (len(problems), "s"[:len(problems) > 1])))
    return 1 if problems else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
