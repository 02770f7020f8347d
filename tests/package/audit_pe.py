#!/usr/bin/env python3
# SPDX-License-Identifier: GPL-3.0-or-later
"""Audit of the shipped Windows library (a PE DLL): what it imports and
what it exports.

    audit_pe.py subdiv_pia.dll [--header csrc/include/subdiv_pia.h]

Passes when the DLL imports only Windows system DLLs (KERNEL32 and the C
runtime, msvcrt or the universal CRT's api-ms-win-crt-*): the GCC runtime,
libstdc++ and winpthreads are inside it; and exports exactly the functions
the header declares with SPIA_API.  Needs binutils' objdump for PE
(x86_64-w64-mingw32-objdump, or objdump where it reads PE).
"""
import argparse
import os
import re
import shutil
import subprocess
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from audit_elf import export_problems  # noqa: E402

SYSTEM_DLLS = re.compile(r"^(kernel32|msvcrt|ucrtbase|api-ms-win-crt-[a-z0-9-]+|advapi32|ntdll)\.dll$", re.I)


def objdump():
    for name in ("x86_64-w64-mingw32-objdump", "objdump"):
        if shutil.which(name):
            return name
    raise RuntimeError("no objdump for PE files")


def pe_tables(path):
    out = subprocess.run([objdump(), "-p", path], check=True, stdout=subprocess.PIPE, text=True).stdout
    imports = re.findall(r"DLL Name: (\S+)", out)
    exports = []
    table = out.split("[Ordinal/Name Pointer] Table", 1)
    if len(table) == 2:
        for line in table[1].splitlines()[1:]:
            m = re.match(r"\s*\[\s*\d+\]\s+(\S+)", line)
            if not m:
                break
            exports.append(m.group(1))
    header = subprocess.run([objdump(), "-f", path], check=True, stdout=subprocess.PIPE, text=True).stdout
    machine = re.search(r"^architecture:\s*([^,\s]+)", header, re.M)
    return imports, exports, machine.group(1) if machine else "?"


def audit(path, header=None):
    problems = []
    imports, exports, machine = pe_tables(path)
    for dll in imports:
        if not SYSTEM_DLLS.match(dll):
            problems.append("imports %s, which is not a Windows system DLL" % dll)
    problems += export_problems(exports, header)
    if "x86-64" not in machine:
        problems.append("architecture %s, not x86-64" % machine)
    report = {"architecture": machine, "imports": ", ".join(imports) or "none",
              "exported": "%d names, %d outside spia_*" % (len(exports), sum(not e.startswith("spia_") for e in exports)),
              "size": "%.2f MB" % (os.path.getsize(path) / 1e6)}
    return report, problems


def main(argv):
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("library")
    parser.add_argument("--header")
    args = parser.parse_args(argv)
    report, problems = audit(args.library, args.header)
    print("PE audit of %s\n| check | found |\n|---|---|" % args.library)
    for key, value in report.items():
        print("| %s | %s |" % (key, value))
    for problem in problems:
        print("FAIL: " + problem)
    print("audit: %s" % ("passed" if not problems else "%d problems" % len(problems)))
    return 1 if problems else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
