# SPDX-License-Identifier: GPL-3.0-or-later
"""Clean Debian userlands for building and testing: debootstrap chroots
under build/chroots, kept from one run to the next, and commands run inside
them in a private mount namespace (its mounts vanish with the process).

Standard library only; needs root, debootstrap and util-linux's unshare.
"""
import glob
import json
import os
import re
import shlex
import shutil
import subprocess
import sys

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
BUILD = os.path.join(ROOT, "build")
CHROOTS = os.path.join(BUILD, "chroots")
DEFAULT_MIRROR = "http://deb.debian.org/debian"
CODENAMES = {"11": "bullseye", "12": "bookworm", "13": "trixie", "14": "forky"}
READY = ".subdiv_pia-ready"


def log(message):
    print(message, flush=True)


def run(cmd, **kwargs):
    log("+ " + " ".join(shlex.quote(str(c)) for c in cmd))
    return subprocess.run([str(c) for c in cmd], check=True, **kwargs)


def host_codename():
    """The machine's Debian release: bookworm, trixie, ..."""
    try:
        with open("/etc/os-release") as f:
            for line in f:
                if line.startswith("VERSION_CODENAME="):
                    name = line.split("=", 1)[1].strip().strip('"')
                    if name:
                        return name
    except OSError:
        pass
    with open("/etc/debian_version") as f:
        major = f.read().strip().split(".")[0]
    return CODENAMES.get(major, "stable")


def mirror():
    """The Debian mirror the machine's own apt sources use."""
    candidates = []
    paths = ["/etc/apt/sources.list"] + sorted(glob.glob("/etc/apt/sources.list.d/*"))
    for path in paths:
        try:
            text = open(path).read()
        except OSError:
            continue
        candidates += re.findall(r"^\s*URIs:\s*(\S+)", text, re.M)
        candidates += re.findall(r"^\s*deb\s+(?:\[[^\]]*\]\s+)?(\S+)", text, re.M)
    for uri in candidates:
        uri = uri.rstrip("/")
        if uri.startswith("http") and uri.endswith("/debian"):
            return uri
    return DEFAULT_MIRROR


def in_chroot(path, command, binds=(), env=None, check=True, capture=False):
    """Runs `command` (a shell string) as root inside the chroot at path, with
    /proc, /dev and /sys mounted and each (host_dir, chroot_dir) of binds
    bind-mounted, all in a mount namespace of its own."""
    mounts = ['mount -t proc proc "$R/proc"', 'mount --rbind /dev "$R/dev"', 'mount --rbind /sys "$R/sys"']
    for host_dir, inner in binds:
        os.makedirs(os.path.join(path, inner.lstrip("/")), exist_ok=True)
        mounts.append("mount --bind %s \"$R\"%s" % (shlex.quote(os.path.abspath(host_dir)), shlex.quote(inner)))
    variables = {"PATH": "/usr/sbin:/usr/bin:/sbin:/bin", "HOME": "/root", "LANG": "C.UTF-8",
                 "DEBIAN_FRONTEND": "noninteractive"}
    variables.update(env or {})
    script = " && ".join(mounts) + ' && exec chroot "$R" /usr/bin/env -i %s /bin/sh -c %s' % (
        " ".join("%s=%s" % (k, shlex.quote(v)) for k, v in variables.items()), shlex.quote(command))
    log("+ [chroot %s] %s" % (os.path.basename(path), command))
    return subprocess.run(["unshare", "--mount", "--propagation", "private", "/bin/sh", "-c", script],
                          env=dict(os.environ, R=path), check=check, text=True,
                          stdout=subprocess.PIPE if capture else None)


def _debootstrap(suite, target, mirror_uri):
    keyrings = [None, "/usr/share/keyrings/debian-archive-removed-keys.gpg"]
    last = None
    for keyring in keyrings:
        if keyring and not os.path.exists(keyring):
            continue
        shutil.rmtree(target, ignore_errors=True)
        cmd = ["debootstrap", "--variant=minbase"]
        if keyring:  # an older release, signed by keys this machine has retired
            cmd.append("--keyring=" + keyring)
        cmd += [suite, target, mirror_uri]
        try:
            run(cmd, stdout=subprocess.DEVNULL)
            return
        except subprocess.CalledProcessError as exc:
            last = exc
    raise RuntimeError("debootstrap of %s from %s failed (%s)" % (suite, mirror_uri, last))


def chroot(name, suite, packages=()):
    """A minbase chroot of `suite` with `packages` (no recommends) at
    build/chroots/<name>, made once and kept while its recipe is the same."""
    path = os.path.join(CHROOTS, name)
    recipe = {"suite": suite, "packages": sorted(packages)}
    stamp = os.path.join(path, READY)
    try:
        with open(stamp) as f:
            made = json.load(f)
    except (OSError, ValueError):
        made = None
    if made == recipe:
        return path
    if made and made.get("suite") == suite and set(made.get("packages", [])) <= set(packages):
        # The same release with fewer packages: add the others.
        in_chroot(path, "apt-get update -qq && apt-get install -y -qq --no-install-recommends %s >/dev/null"
                  " && apt-get clean" % " ".join(sorted(set(packages) - set(made.get("packages", [])))))
        with open(stamp, "w") as f:
            json.dump(recipe, f)
        return path
    os.makedirs(CHROOTS, exist_ok=True)
    uri = mirror()
    log("making the %s chroot %s (%s)" % (suite, path, uri))
    _debootstrap(suite, path, uri)
    if packages:
        in_chroot(path, "apt-get update -qq && apt-get install -y -qq --no-install-recommends %s >/dev/null"
                  " && apt-get clean" % " ".join(sorted(packages)))
    with open(stamp, "w") as f:
        json.dump(recipe, f)
    return path


def main(argv):
    """debian.py chroot NAME SUITE [PACKAGE...]: make (or reuse) a chroot and print its path."""
    if len(argv) >= 3 and argv[0] == "chroot":
        print(chroot(argv[1], argv[2], argv[3:]))
        return 0
    if argv == ["codename"]:
        print(host_codename())
        return 0
    print(main.__doc__, file=sys.stderr)
    return 2


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
