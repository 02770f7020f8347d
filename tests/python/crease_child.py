# SPDX-License-Identifier: GPL-3.0-or-later
"""Library calls on one of crease_cases' meshes, run by
crease_cases.run_limited in a child process: prints one line of JSON with
each call's outcome and wall time and the process's peak resident size.

    crease_child.py '{"mesh": "octahedron", "crease": 0.9,
                      "calls": [{"call": "interpolate", "scheme": "LOOP", "quality": 3}]}'

A call is "interpolate", "stencils" or "refine" (with "levels"); its other
keys are the binding's keyword arguments.  A refusal (spia.PiaError) is
reported with its code and message; anything else ends the child.
"""
import json
import os
import resource
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(os.path.dirname(HERE))
sys.path.insert(0, HERE)
# The binding inside the built add-on, as the tests import it (conftest.py).
sys.path.insert(0, os.path.join(ROOT, os.environ.get("SUBDIV_PIA_ADDON_DIR", os.path.join("build", "addon")),
                                "subdiv_pia"))
import spia  # noqa: E402

from crease_cases import creased_mesh  # noqa: E402


def peak_mb():
    """This process's peak resident size: the kernel's VmHWM, which starts
    anew at exec (getrusage's ru_maxrss keeps the parent's size from before
    the exec, pytest's hundreds of megabytes)."""
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith("VmHWM:"):
                    return int(line.split()[1]) / 1024.0
    except OSError:
        pass
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def one(m, call="interpolate", levels=1, **options):
    if call == "interpolate":
        cage, report = spia.interpolate(m, **options)
        return {"status": report.status, "max_error": report.max_error_relative}
    if call == "stencils":
        table = spia.limit_stencils(m, **options)
        return {"rows": table.row_count, "weights": table.weight_count}
    if call == "refine":
        positions, sizes, _ = spia.refine(m, levels, **options)
        return {"faces": int(len(sizes))}
    raise ValueError(call)


def main(mesh, crease, calls):
    p, f, e, c = creased_mesh(mesh, crease)
    m = spia.Mesh.from_faces(p, f.tolist(), edges=e, edge_creases=c)
    out = []
    for call in calls:
        start = time.perf_counter()
        try:
            result = one(m, **call)
        except spia.PiaError as error:
            out.append({"outcome": "refused", "code": error.code, "message": str(error),
                        "seconds": time.perf_counter() - start})
            continue
        out.append({"outcome": "done", "result": result, "seconds": time.perf_counter() - start})
    print(json.dumps({"calls": out, "peak_mb": peak_mb()}))


if __name__ == "__main__":
    main(**json.loads(sys.argv[1]))
