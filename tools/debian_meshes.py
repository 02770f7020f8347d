# SPDX-License-Identifier: GPL-3.0-or-later
"""Real STL meshes from Debian packages, for the hard-set benchmark.

3D-printing software in Debian ships printer beds and parts as STL files,
exported from CAD programs: long thin triangles, vertices where dozens or
hundreds of triangles meet, parts that touch at single vertices or along
edges.  They are not committed here: `fetch()` downloads the package with
`apt-get download` into build/meshes-debian/, unpacks it with
`dpkg-deb -x` and reads the file from there (kept for the next run).

    /usr/bin/python3 tools/debian_meshes.py list PACKAGE...   # STL files in packages, largest first
    /usr/bin/python3 tools/debian_meshes.py fetch             # the benchmark's files, with their sizes

STL is read with numpy alone (binary and ASCII), and identical vertices
(exactly equal coordinates) are welded into an indexed triangle mesh.
Standard library and numpy only; needs apt-get and dpkg-deb.
"""
import glob
import os
import re
import subprocess
import sys

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
CACHE = os.path.join(ROOT, "build", "meshes-debian")

# The benchmark's files: name -> (package, path inside the package, what it is).
MESHES = {
    "lulzbot_taz_pro_bed": ("cura", "/usr/share/cura/resources/meshes/lulzbot_taz_pro_bed.stl",
                            "printer bed (CAD export): triangle fans up to valence 351, "
                            "parts touching at vertices and edges"),
    "zav_maxpro": ("cura", "/usr/share/cura/resources/meshes/zav_maxpro.stl",
                   "printer frame (CAD export): fans up to valence 205, two fans at thousands of vertices"),
    "trimaker_nebula_platform": ("cura", "/usr/share/cura/resources/meshes/trimaker_nebula_platform.stl",
                                 "printer platform (CAD export): parts sharing hundreds of edges"),
    "UltimakerRobot_support": ("cura", "/usr/share/cura/resources/meshes/UltimakerRobot_support.stl",
                               "printable part (CAD export), 94k vertices"),
    "M3x10_screw": ("prusa-slicer", "/usr/share/PrusaSlicer/shapes/M3x10_screw.stl",
                    "M3 x 10 screw from the shape gallery (CAD export), closed"),
    "TriLAB_dq2_bed": ("prusa-slicer", "/usr/share/PrusaSlicer/profiles/TriLAB/dq2_bed.stl",
                       "printer bed (CAD export), closed"),
}


def _run(cmd, **kwargs):
    return subprocess.run(cmd, check=True, capture_output=True, text=True, **kwargs)


def download(package):
    """The .deb of `package` (the candidate version of this machine's apt
    sources), downloaded once into build/meshes-debian/debs/."""
    debs = os.path.join(CACHE, "debs")
    os.makedirs(debs, exist_ok=True)
    found = sorted(glob.glob(os.path.join(debs, package + "_*.deb")))
    if not found:
        try:
            _run(["apt-get", "download", "-q", package], cwd=debs)
        except subprocess.CalledProcessError as e:
            if os.geteuid() != 0:
                raise RuntimeError(f"apt-get download {package} failed: {e.stderr.strip()}") from None
            # a fresh machine may have no package lists yet, or old ones
            _run(["apt-get", "update", "-qq"])
            try:
                _run(["apt-get", "download", "-q", package], cwd=debs)
            except subprocess.CalledProcessError as e2:
                raise RuntimeError(f"apt-get download {package} failed: {e2.stderr.strip()}") from None
        found = sorted(glob.glob(os.path.join(debs, package + "_*.deb")))
        if not found:
            raise RuntimeError(f"apt-get download {package} left no {package}_*.deb in {debs}")
    return found[-1]


def package_version(deb):
    return _run(["dpkg-deb", "-f", deb, "Version"]).stdout.strip()


def unpack(package):
    """(version, folder): `package` unpacked with dpkg-deb -x into
    build/meshes-debian/<package>_<version>/ (once)."""
    deb = download(package)
    version = package_version(deb)
    folder = os.path.join(CACHE, f"{package}_{version}")
    done = os.path.join(folder, ".unpacked")
    if not os.path.exists(done):
        os.makedirs(folder, exist_ok=True)
        _run(["dpkg-deb", "-x", deb, folder])
        open(done, "w").close()
    return version, folder


def stl_files(package):
    """[(path inside the package, bytes)] of the STL files in `package`, largest first."""
    deb = download(package)
    listing = _run(["dpkg-deb", "-c", deb]).stdout.splitlines()
    files = []
    for line in listing:
        parts = line.split(None, 5)
        if len(parts) == 6 and parts[5].lower().endswith(".stl") and parts[0].startswith("-"):
            files.append((parts[5].lstrip("."), int(parts[2])))
    return sorted(files, key=lambda f: -f[1])


def read_stl_triangles(path):
    """The triangles of an STL file, (T, 3, 3) float32.  Binary when the
    size is that of a binary file with the header's triangle count (binary
    files may start with "solid" too), ASCII otherwise."""
    with open(path, "rb") as fh:
        data = fh.read()
    if len(data) >= 84:
        count = int(np.frombuffer(data, "<u4", 1, 80)[0])
        if len(data) == 84 + 50 * count:
            record = np.dtype([("normal", "<f4", 3), ("corners", "<f4", (3, 3)), ("attribute", "<u2")])
            return np.frombuffer(data, record, count, 84)["corners"].astype(np.float32)
    text = data.decode("ascii", errors="replace")
    if not text.lstrip().lower().startswith("solid"):
        raise ValueError(f"{path}: neither a binary STL (size) nor an ASCII one (no 'solid')")
    numbers = re.findall(r"vertex\s+(\S+)\s+(\S+)\s+(\S+)", text)
    corners = np.asarray(numbers, dtype=np.float64).astype(np.float32)
    if len(corners) % 3:
        raise ValueError(f"{path}: {len(corners)} vertices, not a whole number of triangles")
    return corners.reshape(-1, 3, 3)


def weld(triangles):
    """An indexed mesh from triangle soup: corners with exactly the same
    coordinates become one vertex (np.unique on the float32 triples).
    Triangles that then use a vertex twice (zero-length edges in the file)
    are dropped, as the library refuses them; returns (positions (N, 3)
    float32, faces (T', 3) int32, dropped count).  Vertices are numbered in
    the order the triangles first use them."""
    corners = np.ascontiguousarray(triangles.reshape(-1, 3), dtype=np.float32)
    corners = corners + np.float32(0.0)  # -0.0 and 0.0 are the same point
    keys = corners.view(np.dtype((np.void, 12))).ravel()
    _, first, inverse = np.unique(keys, return_index=True, return_inverse=True)
    # numbered in the order the file first uses them, not in np.unique's
    # order of the coordinates' bytes (keeps the file's locality)
    order = np.argsort(first)
    number = np.empty(len(first), np.int64)
    number[order] = np.arange(len(first))
    positions = corners[first[order]]
    faces = number[inverse.ravel()].reshape(-1, 3).astype(np.int32)
    keep = (faces[:, 0] != faces[:, 1]) & (faces[:, 1] != faces[:, 2]) & (faces[:, 2] != faces[:, 0])
    faces = faces[keep]
    used = np.zeros(len(positions), bool)
    used[faces.ravel()] = True
    if not used.all():  # vertices only the dropped triangles had
        remap = np.cumsum(used) - 1
        positions, faces = positions[used], remap[faces].astype(np.int32)
    return positions, faces, int((~keep).sum())


def read_stl(path):
    """(positions, faces (T, 3) int32, dropped degenerate triangles) of an STL file."""
    return weld(read_stl_triangles(path))


def fetch(name):
    """(positions, faces, provenance) of one of MESHES: provenance is a dict
    with package, version, path, triangles in the file and dropped ones."""
    package, path, _what = MESHES[name]
    version, folder = unpack(package)
    triangles = read_stl_triangles(os.path.join(folder, path.lstrip("/")))
    positions, faces, dropped = weld(triangles)
    return positions, faces, dict(package=package, version=version, path=path,
                                  file_triangles=len(triangles), dropped=dropped)


def main(argv):
    if len(argv) >= 3 and argv[1] == "list":
        for package in argv[2:]:
            version = package_version(download(package))
            for path, size in stl_files(package):
                print(f"{package}\t{version}\t{size}\t{path}")
    elif len(argv) == 2 and argv[1] == "fetch":
        for name in MESHES:
            positions, faces, info = fetch(name)
            print(f"{name}: {len(positions)} vertices, {len(faces)} triangles "
                  f"({info['dropped']} degenerate dropped) from {info['package']} {info['version']} {info['path']}")
    else:
        sys.exit(__doc__)


if __name__ == "__main__":
    main(sys.argv)
