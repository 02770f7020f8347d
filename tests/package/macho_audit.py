#!/usr/bin/env python3
# SPDX-License-Identifier: GPL-3.0-or-later
"""Mach-O audit of the shipped macOS libraries (and of the C test programs
built with them): what they need from the system, what they show a host
process, and, on arm64, their ad-hoc code signature.

    python tests/package/macho_audit.py [--header H] [--arch arm64|x86_64] FILE...

Needs LIEF (`pip install lief`; tools/package.py's build_macos_* run it
with build/venv-macos/bin/python).  Prints each check, PASS or FAIL, and
exits 1 when any fails.

For a library (MH_DYLIB):
- load commands: it loads /usr/lib/libSystem.B.dylib and nothing else (no
  libc++.dylib: the C++ runtime is inside);
- exports: exactly the functions csrc/include/subdiv_pia.h declares with
  SPIA_API, plus at most the linker's own __mh_dylib_header and
  ___dso_handle;
- imports: every undefined symbol and every binding (dyld info or chained
  fixups) resolved from libSystem by two-level namespace; no weak
  bindings, no weak definitions (dyld coalesces those across every image in
  the process: Blender's libc++ and OpenSubdiv could take them over);
- stripped: no debug map (stabs), no local symbols but the linker's thunks;
- LC_BUILD_VERSION: platform macOS, minimum macOS 11.0;
- CPU type: the one the file's path names (macos-arm64 / aarch64 -> ARM64,
  macos-x64 / x86_64 -> X86_64), or --arch;
- code signature: on arm64 required, ad hoc, its code directory's page
  hashes (SHA-256) recomputed over the file equal those stored, and so do
  its special slots; on x86_64 optional (Intel Macs load unsigned
  libraries), checked the same way when present.

For a program (MH_EXECUTE, the C tests): the same but for exports, and it
may load the library under test (@rpath/libsubdiv_pia.dylib) beside
libSystem, taking only spia_* from it; its own weak definitions (a C++
program's libc++ and inline functions) are coalesced as usual.
"""
import argparse
import hashlib
import os
import re
import struct
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(os.path.dirname(HERE))
HEADER = os.path.join(ROOT, "csrc", "include", "subdiv_pia.h")
LIBSYSTEM = "/usr/lib/libSystem.B.dylib"
LIBRARY_INSTALL_NAMES = re.compile(r"^(@rpath/|@loader_path/|@executable_path/)?libsubdiv_pia\.dylib$")
LINKER_EXPORTS = {"__mh_dylib_header", "___dso_handle"}
MIN_MACOS = (11, 0, 0)

# Apple's cs_blobs.h (xnu: osfmk/kern/cs_blobs.h), all big-endian.
CSMAGIC_EMBEDDED_SIGNATURE = 0xFADE0CC0
CSMAGIC_CODEDIRECTORY = 0xFADE0C02
CSSLOT_CODEDIRECTORY = 0
CSSLOT_ALTERNATE_CODEDIRECTORIES = 0x1000
CSSLOT_ALTERNATE_CODEDIRECTORY_MAX = 5
CSSLOT_SIGNATURESLOT = 0x10000
CS_ADHOC = 0x2
CS_LINKER_SIGNED = 0x20000
HASHES = {1: ("sha1", 20), 2: ("sha256", 32), 3: ("sha256", 20), 4: ("sha384", 48)}
CS_HASHTYPE_SHA256 = 2

results = []


def check(name, ok, detail):
    results.append((name, ok))
    print("%s %s: %s" % ("PASS" if ok else "FAIL", name, detail), flush=True)
    return ok


def header_api(header):
    """The functions the header declares with SPIA_API (as audit_elf.py reads them)."""
    text = open(header).read()
    return set(re.findall(r"SPIA_API\s+[^;{(]*?\b(spia_\w+)\s*\(", text))


def expected_cpu(path, arch):
    """'ARM64' or 'X86_64' from --arch or the path, else None."""
    text = (arch or path).lower()
    if re.search(r"arm64|aarch64", text):
        return "ARM64"
    if re.search(r"x86_64|x86-64|x64|amd64", text):
        return "X86_64"
    return None


# --------------------------------------------------------------------------
# Code signature (LC_CODE_SIGNATURE), parsed here from the bytes
# --------------------------------------------------------------------------

def code_directories(blob):
    """[(slot type, offset in blob, bytes)] of the embedded signature's code
    directories, and every blob of the superblob as {type: bytes}."""
    magic, length, count = struct.unpack_from(">III", blob, 0)
    if magic != CSMAGIC_EMBEDDED_SIGNATURE:
        raise ValueError("signature magic 0x%08x, not an embedded signature (0x%08x)" % (
            magic, CSMAGIC_EMBEDDED_SIGNATURE))
    if length > len(blob):
        raise ValueError("superblob length %d beyond the signature's %d bytes" % (length, len(blob)))
    blobs, directories = {}, []
    for i in range(count):
        slot, offset = struct.unpack_from(">II", blob, 12 + 8 * i)
        _magic, size = struct.unpack_from(">II", blob, offset)
        data = blob[offset:offset + size]
        if len(data) != size:
            raise ValueError("blob in slot 0x%x runs past the superblob" % slot)
        blobs[slot] = data
        if slot == CSSLOT_CODEDIRECTORY or (
                CSSLOT_ALTERNATE_CODEDIRECTORIES <= slot < CSSLOT_ALTERNATE_CODEDIRECTORIES +
                CSSLOT_ALTERNATE_CODEDIRECTORY_MAX):
            directories.append((slot, data))
    return directories, blobs


def verify_code_directory(cd, blobs, content, signature_offset):
    """Problems with one code directory (list of str) and facts about it (dict)."""
    problems = []
    (magic, length, version, flags, hash_offset, ident_offset, n_special, n_code, code_limit, hash_size,
     hash_type, _platform, page_shift) = struct.unpack_from(">IIIIIIIIIBBBB", cd, 0)
    if magic != CSMAGIC_CODEDIRECTORY:
        return ["code directory magic 0x%08x" % magic], {}
    if version >= 0x20300 and len(cd) >= 0x38:
        code_limit64 = struct.unpack_from(">Q", cd, 0x30)[0]
        if code_limit64:
            code_limit = code_limit64
    identifier = cd[ident_offset:cd.index(b"\0", ident_offset)].decode("utf-8", "replace")
    name, size = HASHES.get(hash_type, (None, None))
    facts = {"identifier": identifier, "version": "0x%x" % version, "flags": "0x%x" % flags,
             "hash": name or "type %d" % hash_type, "page size": 1 << page_shift if page_shift else "whole file",
             "code slots": n_code, "special slots": n_special, "code limit": code_limit}
    if name is None or size != hash_size:
        return problems + ["hash type %d with hash size %d is not one cs_blobs.h defines" % (hash_type, hash_size)], facts
    if hash_type != CS_HASHTYPE_SHA256:
        problems.append("hash type %s, not SHA-256" % facts["hash"])
    if code_limit != signature_offset:
        problems.append("code limit %d, but the signature starts at %d: the hashes do not cover the whole file "
                        "before it" % (code_limit, signature_offset))
    page = (1 << page_shift) if page_shift else code_limit
    expected_slots = (code_limit + page - 1) // page if code_limit else 0
    if n_code != expected_slots:
        problems.append("%d code slots for %d bytes in pages of %d (expected %d)" % (
            n_code, code_limit, page, expected_slots))
    if hash_offset + n_code * hash_size > len(cd) or hash_offset < n_special * hash_size:
        return problems + ["hash slots outside the code directory"], facts
    bad = []
    for i in range(n_code):
        stored = cd[hash_offset + i * hash_size:hash_offset + (i + 1) * hash_size]
        computed = hashlib.new(name, content[i * page:min((i + 1) * page, code_limit)]).digest()[:hash_size]
        if stored != computed:
            bad.append(i)
    if bad:
        problems.append("%d of %d page hashes differ (pages %s)" % (len(bad), n_code, ", ".join(map(str, bad[:8]))))
    facts["page hashes"] = "%d of %d equal" % (n_code - len(bad), n_code)
    # Special slots -1, -2, ...: the hash of the superblob's blob of that
    # type (requirements, entitlements, ...), or zeros where there is none.
    for k in range(1, n_special + 1):
        stored = cd[hash_offset - k * hash_size:hash_offset - (k - 1) * hash_size]
        if k in blobs:
            ok = stored == hashlib.new(name, blobs[k]).digest()[:hash_size]
        else:
            ok = stored == bytes(hash_size)
        if not ok:
            problems.append("special slot -%d does not match %s" % (k, "its blob" if k in blobs else "an absent blob"))
    return problems, facts


def check_signature(label, binary, content, required):
    command = binary.code_signature if binary.has_code_signature else None
    if command is None:
        return check(label + " signature", not required,
                     "none%s" % (": arm64 code must be signed to run" if required else
                                 " (x86_64: Intel Macs load unsigned libraries)"))
    offset, size = command.data_offset, command.data_size
    blob = content[offset:offset + size]
    problems = []
    if offset + size != len(content):
        problems.append("the signature (%d + %d bytes) does not end the file (%d bytes)" % (offset, size, len(content)))
    try:
        directories, blobs = code_directories(blob)
    except (ValueError, struct.error) as exc:
        return check(label + " signature", False, "LC_CODE_SIGNATURE at %d, %d bytes: %s" % (offset, size, exc))
    if not directories:
        return check(label + " signature", False, "no code directory in the signature")
    details = []
    adhoc = True
    for slot, cd in directories:
        cd_problems, facts = verify_code_directory(cd, blobs, content, offset)
        problems += ["code directory 0x%x: %s" % (slot, p) for p in cd_problems]
        flags = int(facts.get("flags", "0"), 16)
        adhoc = adhoc and bool(flags & CS_ADHOC)
        kind = ", ".join(n for bit, n in ((CS_ADHOC, "ad hoc"), (CS_LINKER_SIGNED, "linker-signed")) if flags & bit)
        details.append("code directory %s (%s): %s, %s pages of %s bytes, page hashes %s, identifier %s" % (
            "0x%x" % slot, kind or "flags " + facts.get("flags", "?"), facts.get("hash"), facts.get("code slots"),
            facts.get("page size"), facts.get("page hashes", "not checked"), facts.get("identifier")))
    cms = blobs.get(CSSLOT_SIGNATURESLOT, b"")
    if not adhoc:
        problems.append("not ad hoc (flags lack CS_ADHOC)")
    details.append("CMS signature blob: %s" % ("%d bytes" % len(cms) if len(cms) > 8 else "none (ad hoc)"))
    return check(label + " signature", not problems, "; ".join(details + problems))


# --------------------------------------------------------------------------
# The audit of one file
# --------------------------------------------------------------------------

def load_commands(binary, lief):
    kinds = {lief.MachO.LoadCommand.TYPE.LOAD_DYLIB: "", lief.MachO.LoadCommand.TYPE.LOAD_WEAK_DYLIB: " (weak)",
             lief.MachO.LoadCommand.TYPE.REEXPORT_DYLIB: " (re-exported)",
             lief.MachO.LoadCommand.TYPE.LAZY_LOAD_DYLIB: " (lazy)",
             lief.MachO.LoadCommand.TYPE.LOAD_UPWARD_DYLIB: " (upward)"}
    return [(c.name, kinds[c.command]) for c in binary.commands if c.command in kinds]


def bindings(binary):
    """(symbol, library name or ordinal, weak class) of every binding dyld makes."""
    found = []
    if binary.has_dyld_info:
        items = binary.dyld_info.bindings
    elif binary.has_dyld_chained_fixups:
        items = binary.dyld_chained_fixups.bindings
    else:
        items = []
    for b in items:
        library = b.library.name if b.has_library else "ordinal %d" % b.library_ordinal
        symbol = b.symbol.name if b.has_symbol else "?"
        weak = "WEAK" in str(getattr(b, "binding_class", ""))
        found.append((symbol, library, weak))
    return found


def audit(path, header, arch=None):
    import lief
    lief.logging.disable()  # LIEF warns about sections that are not its business
    label = os.path.relpath(path) if not os.path.relpath(path).startswith("..") else path
    fat = lief.MachO.parse(path)
    if fat is None or fat.size != 1:
        return check(label + " format", False, "not a thin Mach-O file")
    binary = fat.at(0)
    with open(path, "rb") as f:
        content = f.read()
    kind = binary.header.file_type
    is_library = kind == lief.MachO.Header.FILE_TYPE.DYLIB
    is_program = kind == lief.MachO.Header.FILE_TYPE.EXECUTE
    if not (is_library or is_program):
        return check(label + " format", False, "file type %s, neither a library nor a program" % kind)
    print("%s: %s, %s, %d bytes" % (label, "library" if is_library else "program",
                                    str(binary.header.cpu_type).split(".")[-1], len(content)))

    cpu = str(binary.header.cpu_type).split(".")[-1]
    want = expected_cpu(path, arch)
    check(label + " cpu", want is not None and cpu == want,
          "%s, %s" % (cpu, "expected %s from %s" % (want, "--arch" if arch else "its path") if want
                      else "no architecture in its path (pass --arch)"))

    loads = load_commands(binary, lief)
    foreign = [(n, k) for n, k in loads if n != LIBSYSTEM and not (is_program and not k and
                                                                     LIBRARY_INSTALL_NAMES.match(n))]
    check(label + " loads", LIBSYSTEM in [n for n, _k in loads] and not foreign,
          ", ".join(n + k for n, k in loads) or "nothing")

    flags = [str(f).split(".")[-1] for f in binary.header.flags_list]
    weak_flags = [f for f in flags if f in ("WEAK_DEFINES", "BINDS_TO_WEAK", "FORCE_FLAT")]
    binds = bindings(binary)
    ordinal_names = {i + 1: n for i, (n, _k) in enumerate(loads)}
    # nlist: external (N_EXT), not a debugging entry (N_STAB), type N_UNDF, no value (not common)
    undefined = [s for s in binary.symbols if s.raw_type & 0x01 and not s.raw_type & 0xE0
                 and (s.raw_type & 0x0E) == 0 and s.value == 0]
    problems = []
    for s in undefined:
        ordinal = (s.description >> 8) & 0xFF   # GET_LIBRARY_ORDINAL(n_desc)
        library = ordinal_names.get(ordinal, "ordinal %d" % ordinal)
        if library != LIBSYSTEM and not (LIBRARY_INSTALL_NAMES.match(library) and s.name.startswith("_spia_")):
            problems.append("%s from %s" % (s.name, library))
    for symbol, library, weak in binds:
        if weak:
            # A C++ program's own weak definitions (libc++'s operator new,
            # inline functions) are coalesced by dyld at its start: harmless
            # in a test program, a way in for the host's copies in a library.
            if is_library:
                problems.append("weak binding of %s" % symbol)
        elif library != LIBSYSTEM and not (LIBRARY_INSTALL_NAMES.match(library) and symbol.startswith("_spia_")):
            problems.append("%s bound from %s" % (symbol, library))
    if "TWOLEVEL" not in flags:
        problems.append("not two-level namespace")
    problems += ["header flag %s" % f for f in weak_flags if is_library or f == "FORCE_FLAT"]
    by_library = {}
    for symbol, library, weak in binds:
        by_library.setdefault("weak definitions" if weak else library, set()).add(symbol)
    check(label + " imports", not problems,
          "%d undefined symbols, %d bindings (%s)%s" % (
              len(undefined), len(binds),
              ", ".join("%d from %s" % (len(v), k) for k, v in sorted(by_library.items())) or "none",
              "; " + "; ".join(sorted(set(problems))[:10]) if problems else "; flags " + " ".join(flags)))

    if is_library:
        exported = sorted(s.name for s in binary.exported_symbols)
        api = {"_" + n for n in header_api(header)}
        missing = sorted(api - set(exported))
        extra = sorted(set(exported) - api - LINKER_EXPORTS)
        detail = "%d names: %d of the %d SPIA_API functions%s" % (
            len(exported), len(api & set(exported)), len(api),
            "".join(", " + n for n in sorted(set(exported) & LINKER_EXPORTS)))
        if missing:
            detail += "; MISSING " + ", ".join(missing)
        if extra:
            detail += "; EXTRA %d: %s" % (len(extra), ", ".join(extra[:10]))
        check(label + " exports", not missing and not extra, detail)

    if is_library:
        # Stripped by the linker (-x -S): no debug map (stabs naming every
        # object file with its build path and time), local symbols only
        # where the linker adds its own (Zig's __thunk stubs).
        stabs = [sym for sym in binary.symbols if sym.raw_type & 0xE0]
        local = [sym.name for sym in binary.symbols if not sym.raw_type & 0xE0 and not sym.raw_type & 0x01]
        named = [n for n in local if not n.endswith("__thunk")]
        check(label + " stripped", not stabs and not named,
              "%d debug-map (stab) entries, %d local symbols (%d the linker's thunks)%s" % (
                  len(stabs), len(local), len(local) - len(named),
                  ", e.g. " + ", ".join(named[:5]) if named else ""))

    version = binary.build_version if binary.has_build_version else None
    if version is not None:
        minos = tuple(version.minos)
        platform = str(version.platform).split(".")[-1]
        check(label + " minimum macOS", platform == "MACOS" and minos == MIN_MACOS,
              "LC_BUILD_VERSION platform %s, minos %s, sdk %s" % (
                  platform, ".".join(map(str, minos)), ".".join(map(str, version.sdk))))
    elif binary.has_version_min:
        minos = tuple(binary.version_min.version)
        check(label + " minimum macOS", minos == MIN_MACOS, "LC_VERSION_MIN_MACOSX %s" % ".".join(map(str, minos)))
    else:
        check(label + " minimum macOS", False, "no LC_BUILD_VERSION nor LC_VERSION_MIN_MACOSX")

    check_signature(label, binary, content, required=cpu == "ARM64")
    return True


def main(argv):
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("files", nargs="+", metavar="FILE")
    parser.add_argument("--header", default=HEADER, help="the header whose SPIA_API functions are the exports")
    parser.add_argument("--arch", choices=["arm64", "x86_64"], help="the CPU expected (default: from each path)")
    args = parser.parse_args(argv)
    try:
        import lief  # noqa: F401
    except ImportError:
        print("macho_audit.py needs LIEF (pip install lief; tools/package.py installs it in build/venv-macos)",
              file=sys.stderr)
        return 2
    for path in args.files:
        audit(path, args.header, args.arch)
    failed = [n for n, ok in results if not ok]
    print("macho audit: %d passed, %d failed" % (len(results) - len(failed), len(failed)))
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
