# SPDX-License-Identifier: GPL-3.0-or-later
"""Plain OBJ reading for the tests (positions and faces, OpenSubdiv 't crease' tags)."""
import numpy as np


def read_obj(path):
    """Returns (positions (N,3) float32, faces list of lists, creases dict {(a,b): sharpness})."""
    verts, faces, creases = [], [], {}
    with open(path) as fh:
        for line in fh:
            p = line.split()
            if not p:
                continue
            if p[0] == "v":
                verts.append([float(x) for x in p[1:4]])
            elif p[0] == "f":
                faces.append([int(x.split("/")[0]) - 1 for x in p[1:]])
            elif p[0] == "t" and p[1] == "crease":
                ni, nf = (int(x) for x in p[2].split("/")[:2])
                ints = [int(x) for x in p[3:3 + ni]]
                flts = [float(x) for x in p[3 + ni:3 + ni + nf]]
                for k in range(len(ints) - 1):
                    creases[(ints[k], ints[k + 1])] = flts[0] if flts else 10.0
    return np.asarray(verts, dtype=np.float32).reshape(-1, 3), faces, creases
