# SPDX-License-Identifier: GPL-3.0-or-later
"""Benchmark: Loop-surface interpolation of the shipped triangle meshes, set
beside the numbers of the Loop PIA papers.

    /usr/bin/python3 bench/bench_loop_papers.py [--out out/loop_papers.md] [--plot out/loop_papers_convergence.png]

The papers:

* Wang et al., GS-PIA for Loop surfaces, Table 1: spectral radius of the
  iteration matrix of PIA (I - L), WPIA with the best weight (I - w L,
  w = 2 / (lambda_min + lambda_max)) and GS-PIA (-(D + Lo)^-1 U, Gauss-Seidel
  on L = D + Lo + U in vertex order), and E10/E0, E_k being the max error
  |P_i - (L V_k)_i| after k iterations;
* Cheng et al., Loop PIA for open meshes, Table 1: iterations to reach a max
  error of 1e-3, the data normalized to a unit bounding box; boundaries with
  Hoppe et al.'s rules (the library's boundary_rule HOPPE).

Every mesh is reduced to the vertices its faces use and scaled so that the
largest side of its bounding box is 1.  The library measures errors relative
to the bounding-box diagonal d, so an absolute error e in the unit box is the
tolerance e / d.  Spectral radii are computed here with scipy from the limit
stencil matrix L, independently of the library's solvers; E10/E0 and the
iteration counts come from runs of the library.  Writes a Markdown table and
a plot of the error histories.
"""
import argparse
import os
import sys
import time

import numpy as np
import scipy.linalg as la
import scipy.sparse as sp
import scipy.sparse.linalg as sla

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from harness import DATA, ROOT, addon_on_path  # noqa: E402

addon_on_path()
sys.path.insert(0, os.path.join(ROOT, "tests", "python"))

from meshio import read_obj  # noqa: E402
from subdiv_pia import native  # noqa: E402

MESHES = [("bunny", "closed"), ("elephant-with-holes", "open"), ("bun_zipper", "open"), ("teapot", "open")]
METHODS = ("PIA", "WPIA", "GS_PIA", "AUTO")
LABEL = {"PIA": "PIA", "WPIA": "WPIA", "GS_PIA": "GS-PIA", "AUTO": "AUTO"}
TARGETS = (1e-3, 1e-6)        # absolute max errors in the unit box
MAX_ITERATIONS = 5000
HISTORY_ITERATIONS = 400      # runs with a tiny tolerance, for E10/E0 and the plot
DENSE_CHECK = 3000            # dense eigenvalues of L as a cross-check up to this many vertices
DENSE_CHECK_GS = 1000         # and of the Gauss-Seidel matrix up to this many
EIGS_GS_VERTICES = 10000      # above this, GS-PIA's radius by power iteration
POWER_STEPS = 3000

# Wang et al., Table 1 (three closed meshes of 477, 1618 and 8604 vertices).
PAPER_RHO = {"PIA": (0.769, 0.783, 0.815), "WPIA": (0.624, 0.643, 0.688), "GS_PIA": (0.312, 0.267, 0.341)}
PAPER_E10 = {"PIA": (0.028, 0.017, 0.018), "WPIA": (0.002, 0.001, 0.002), "GS_PIA": (1.08e-5, 2.12e-6, 1.10e-5)}
# Cheng et al. (open meshes), Table 1: iterations to a max error of 1e-3.
PAPER_ITERS_1E3 = (6, 13)


def load(name):
    """Positions scaled to a unit box, faces, vertex count in the file."""
    P, faces, _ = read_obj(os.path.join(DATA, name + ".obj"))
    F = np.asarray(faces, dtype=np.int64)
    if F.ndim != 2 or F.shape[1] != 3:
        raise SystemExit(f"{name}: not a triangle mesh")
    used = np.unique(F)
    remap = np.full(len(P), -1, dtype=np.int64)
    remap[used] = np.arange(len(used))
    F, Q = remap[F], P[used].astype(np.float64)
    lo, hi = Q.min(axis=0), Q.max(axis=0)
    Q = ((Q - lo) / (hi - lo).max()).astype(np.float32)
    return Q, F, len(P)


def valence_range(F, n):
    E = np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]])
    E.sort(axis=1)
    E = np.unique(E, axis=0)
    val = np.bincount(E.ravel(), minlength=n)
    return int(val.min()), int(val.max())


def boundary_vertex_count(F):
    E = np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]])
    E.sort(axis=1)
    edges, count = np.unique(E, axis=0, return_counts=True)
    return len(np.unique(edges[count == 1].ravel()))


def spectral_radii(L, notes, tag):
    """rho of I - L, I - w L (best w) and the Gauss-Seidel matrix of L, and lambda_min, lambda_max of L."""
    n = L.shape[0]
    lam_max = sla.eigs(L, k=1, which="LR", return_eigenvectors=False, tol=1e-10)[0]
    # the eigenvalue nearest 0, by shift-invert (a sparse LU of L)
    lam_min = sla.eigs(L, k=1, sigma=0.0, which="LM", return_eigenvectors=False, tol=1e-10)[0]
    imag = max(abs(lam_max.imag), abs(lam_min.imag))
    if imag > 1e-8:
        notes.append(f"{tag}: extreme eigenvalues of L are complex (imaginary part {imag:.1e})")
    lo, hi = lam_min.real, lam_max.real
    w = 2.0 / (lo + hi)
    # with a real spectrum in [lo, hi], rho(I - wL) = max(|1 - w lo|, |1 - w hi|)
    rho_pia = max(abs(1.0 - lo), abs(1.0 - hi))
    rho_wpia = max(abs(1.0 - w * lo), abs(1.0 - w * hi))

    DLo = sp.tril(L, format="csc")
    U = sp.triu(L, 1, format="csr")
    if n <= EIGS_GS_VERTICES:
        def gs(x):
            return -sla.spsolve_triangular(DLo.tocsr(), U @ x, lower=True)
    else:
        # scipy's spsolve_triangular loops in Python; SuperLU on the
        # triangular matrix with its natural order does the same solve
        lu = sla.splu(DLo, permc_spec="NATURAL", diag_pivot_thresh=0.0, options=dict(SymmetricMode=True))

        def gs(x):
            return -lu.solve(U @ x)
    rho_gs, gs_how = None, "eigs"
    if n <= EIGS_GS_VERTICES:
        op = sla.LinearOperator((n, n), matvec=gs, dtype=np.float64)
        try:
            rho_gs = abs(sla.eigs(op, k=1, which="LM", return_eigenvectors=False, tol=1e-8, ncv=30,
                                  maxiter=500)[0])
        except sla.ArpackNoConvergence:
            pass
    if rho_gs is None:
        # power iteration: the geometric mean of the growth over the second
        # half of the steps (a complex dominant pair makes single steps swing)
        x = np.random.default_rng(1).standard_normal(n)
        x /= np.linalg.norm(x)
        logs = np.empty(POWER_STEPS)
        for k in range(POWER_STEPS):
            x = gs(x)
            nx = np.linalg.norm(x)
            logs[k] = np.log(nx)
            x /= nx
        rho_gs = float(np.exp(logs[POWER_STEPS // 2:].mean()))
        spread = float(np.exp(logs[-POWER_STEPS // 4:].mean()) - np.exp(logs[POWER_STEPS // 2:-POWER_STEPS // 4].mean()))
        gs_how = f"power iteration, {POWER_STEPS} steps (last two quarters differ by {abs(spread):.1e})"

    if n <= DENSE_CHECK:
        A = L.toarray()
        ev = la.eigvals(A)
        dev = max(abs(np.abs(1.0 - ev).max() - rho_pia), abs(np.abs(1.0 - w * ev).max() - rho_wpia))
        what = "PIA and WPIA radii"
        if n <= DENSE_CHECK_GS:
            G = -la.solve_triangular(np.tril(A), np.triu(A, 1), lower=True)
            dev = max(dev, abs(np.abs(la.eigvals(G)).max() - rho_gs))
            what = "all three radii"
        notes.append(f"{tag}: dense check (scipy.linalg.eigvals, all {n} eigenvalues): max |imag| of L's "
                     f"spectrum {np.abs(ev.imag).max():.1e}; {what} differ from the sparse ones by at most {dev:.1e}")
    return dict(lam_min=lo, lam_max=hi, w=w, PIA=rho_pia, WPIA=rho_wpia, GS_PIA=rho_gs, gs_how=gs_how)


def run(mesh, rule, method, tolerance, max_iterations):
    _, rep = native.interpolate(mesh, scheme="LOOP", boundary_rule=rule, method=method, tolerance=tolerance,
                                max_iterations=max_iterations)
    return rep


def fmt_e(x):
    return f"{x:.2g}" if x >= 1e-3 else f"{x:.2e}"


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", default=os.path.join(ROOT, "out", "loop_papers.md"))
    ap.add_argument("--plot", default=os.path.join(ROOT, "out", "loop_papers_convergence.png"))
    args = ap.parse_args()
    t_start = time.perf_counter()

    header = ("| mesh | boundary rule | vertices | valence | rho PIA | rho WPIA | rho GS-PIA | E10/E0 PIA | "
              "E10/E0 WPIA | E10/E0 GS-PIA | iterations to 1e-3 (PIA / WPIA / GS-PIA / AUTO) | "
              "iterations to 1e-6 (PIA / WPIA / GS-PIA / AUTO) |")
    rows = [header, "|---|---|---:|---|---:|---:|---:|---:|---:|---:|---|---|"]
    notes, results, histories = [], [], {}
    print("Loop subdivision, limit-point interpolation of the shipped triangle meshes")
    print("Each mesh: only the vertices used by faces, scaled so that the largest side of its bounding box is 1;")
    print("errors below are max |P_i - (L V)_i|; '1e-3' and '1e-6' are absolute in that unit box.\n")
    print("\n".join(rows), flush=True)

    for name, kind in MESHES:
        P, F, n_file = load(name)
        n = len(P)
        vmin, vmax = valence_range(F, n)
        diag = float(np.linalg.norm(P.astype(np.float64).max(axis=0) - P.astype(np.float64).min(axis=0)))
        mesh = native.Mesh.from_faces(P, F.tolist())
        if n != n_file:
            notes.append(f"{name}: {n_file - n} vertices used by no face left out ({n} of {n_file})")
        if kind == "open":
            notes.append(f"{name}: {boundary_vertex_count(F)} boundary vertices")
        rules = ("HOPPE", "SMOOTH") if kind == "open" else ("SMOOTH",)
        for rule in rules:
            tag = f"{name} {rule if kind == 'open' else '(closed)'}"
            L = native.limit_stencils(mesh, scheme="LOOP", boundary_rule=rule).to_scipy().tocsr()
            rad = spectral_radii(L, notes, tag)
            if rad["gs_how"] != "eigs":
                notes.append(f"{tag}: GS-PIA radius by {rad['gs_how']}")
            e10, hist = {}, {}
            for method in METHODS:
                rep = run(mesh, rule, method, 1e-12, HISTORY_ITERATIONS)
                hist[method] = np.concatenate([[rep.initial_max_error_relative], rep.history])
                if rep.unreachable_count:
                    notes.append(f"{tag} {LABEL[method]}: {rep.unreachable_count} vertices cannot be reached")
                if abs(rep.diagonal - diag) > 1e-6 * diag:
                    notes.append(f"{tag}: the library's diagonal {rep.diagonal:.6f} differs from {diag:.6f}")
                if len(rep.history) >= 10:
                    e10[method] = rep.history[9] / rep.initial_max_error_relative
                else:
                    e10[method] = None
                    notes.append(f"{tag} {LABEL[method]}: converged to 1e-12 after {rep.iterations} iterations, "
                                 "before the 10th; no E10")
                if method == "WPIA":
                    notes.append(f"{tag}: lambda(L) in [{rad['lam_min']:.4f}, {rad['lam_max']:.4f}], best WPIA "
                                 f"weight {rad['w']:.4f}; the library estimated {rep.weight:.4f}")
            histories[tag] = hist
            iters = {}
            for target in TARGETS:
                cells = []
                for method in METHODS:
                    rep = run(mesh, rule, method, target / diag, MAX_ITERATIONS)
                    cell = str(rep.iterations)
                    if not rep.converged:
                        cell += f" ({rep.status.lower()})"
                    cells.append(cell)
                    iters[(target, method)] = rep.iterations if rep.converged else None
                iters[target] = " / ".join(cells)
            gs_mark = "" if rad["gs_how"] == "eigs" else "*"
            row = (f"| {name} | {rule if kind == 'open' else '— (closed)'} | {n:,} | {vmin}..{vmax} | "
                   f"{rad['PIA']:.3f} | {rad['WPIA']:.3f} | {rad['GS_PIA']:.3f}{gs_mark} | "
                   + " | ".join("—" if e10[m] is None else fmt_e(e10[m]) for m in ("PIA", "WPIA", "GS_PIA"))
                   + f" | {iters[1e-3]} | {iters[1e-6]} |")
            rows.append(row)
            print(row, flush=True)
            results.append(dict(tag=tag, name=name, rule=rule, kind=kind, n=n, diag=diag, rad=rad, e10=e10, iters=iters))

    legend = ["", "rho: spectral radius of the iteration matrix, from the eigenvalues of the limit matrix L "
              "(scipy eigs; PIA and WPIA from lambda_min and lambda_max of L, WPIA with w = 2/(lambda_min + "
              "lambda_max); GS-PIA: eigs on x -> -(D+Lo)^-1 U x"
              + ("; * = by power iteration)" if any(r["rad"]["gs_how"] != "eigs" for r in results) else ")"),
              "E10/E0: max error after 10 iterations over the initial one (cage = mesh), from library runs "
              "with tolerance 1e-12.",
              "iterations: library runs with tolerance = target / diagonal of the unit box, at most "
              f"{MAX_ITERATIONS} iterations; AUTO is the library's choice (CG on closed meshes, Chebyshev-accelerated PIA on open ones).",
              "Open meshes are solved in one go (not boundary first, then interior)."]
    notes_md = [""] + [f"- {s}" for s in notes]
    print("\n".join(legend))
    print("\n".join(notes_md))

    # --- comparison with the papers ----------------------------------------
    closed = [r for r in results if r["kind"] == "closed"]
    hoppe = [r for r in results if r["kind"] == "open" and r["rule"] == "HOPPE"]
    smooth = [r for r in results if r["kind"] == "open" and r["rule"] == "SMOOTH"]

    def rng(vals, f):
        vals = [v for v in vals if v is not None]
        if not vals:
            return "—"
        return f(min(vals)) if min(vals) == max(vals) else f"{f(min(vals))} .. {f(max(vals))}"

    def verdict(ours, paper):
        ours = [v for v in ours if v is not None]
        if not ours:
            return "no value"
        lo, hi = min(paper), max(paper)
        if all(lo <= v <= hi for v in ours):
            return "inside the papers' range"
        if all(v < lo for v in ours):
            return f"below (ours at most {max(ours) / lo:.2g}x the papers' smallest)"
        if all(v > hi for v in ours):
            return f"above (ours at least {min(ours) / hi:.2g}x the papers' largest)"
        return "overlapping the papers' range"

    cmp_lines = ["", "## Comparison with the papers", "",
                 "| quantity | paper (Wang et al., 3 closed meshes) | ours closed | ours open, HOPPE | "
                 "ours open, SMOOTH | all of ours vs paper |",
                 "|---|---|---|---|---|---|"]
    f3 = (lambda x: f"{x:.3f}")
    for m in ("PIA", "WPIA", "GS_PIA"):
        ours = [r["rad"][m] for r in results]
        cmp_lines.append(f"| rho {LABEL[m]} | {rng(PAPER_RHO[m], f3)} | {rng([r['rad'][m] for r in closed], f3)} | "
                         f"{rng([r['rad'][m] for r in hoppe], f3)} | {rng([r['rad'][m] for r in smooth], f3)} | "
                         f"{verdict(ours, PAPER_RHO[m])} |")
    for m in ("PIA", "WPIA", "GS_PIA"):
        ours = [r["e10"][m] for r in results]
        cmp_lines.append(f"| E10/E0 {LABEL[m]} | {rng(PAPER_E10[m], fmt_e)} | "
                         f"{rng([r['e10'][m] for r in closed], fmt_e)} | {rng([r['e10'][m] for r in hoppe], fmt_e)} | "
                         f"{rng([r['e10'][m] for r in smooth], fmt_e)} | {verdict(ours, PAPER_E10[m])} |")
    ours = [r["iters"][(1e-3, "PIA")] for r in results]
    fi = (lambda x: f"{x}")
    cmp_lines.append(f"| PIA iterations to 1e-3 | {PAPER_ITERS_1E3[0]} .. {PAPER_ITERS_1E3[1]} (Cheng et al., 7 closed "
                     f"meshes; 10 for an open one) | {rng([r['iters'][(1e-3, 'PIA')] for r in closed], fi)} | "
                     f"{rng([r['iters'][(1e-3, 'PIA')] for r in hoppe], fi)} | "
                     f"{rng([r['iters'][(1e-3, 'PIA')] for r in smooth], fi)} | {verdict(ours, PAPER_ITERS_1E3)} |")
    cmp_lines += ["", "Per mesh, rho^10 (the asymptotic E10/E0) beside the measured E10/E0:", ""]
    for r in results:
        parts = []
        for m in ("PIA", "WPIA", "GS_PIA"):
            e = r["e10"][m]
            parts.append(f"{LABEL[m]} {fmt_e(r['rad'][m] ** 10)} vs {'—' if e is None else fmt_e(e)}")
        cmp_lines.append(f"- {r['tag']}: " + "; ".join(parts))
    # the papers' E10/E0 against their own radii
    parts = []
    for m in ("PIA", "WPIA", "GS_PIA"):
        parts.append(f"{LABEL[m]} rho^10 {rng([x ** 10 for x in PAPER_RHO[m]], fmt_e)} vs E10/E0 "
                     f"{rng(PAPER_E10[m], fmt_e)}")
    cmp_lines.append("- paper (Wang et al.): " + "; ".join(parts))
    order_ok = all(r["rad"]["GS_PIA"] < r["rad"]["WPIA"] < r["rad"]["PIA"] for r in results)
    cmp_lines += ["", f"Order rho GS-PIA < rho WPIA < rho PIA as in the paper: "
                  f"{'on every mesh' if order_ok else 'not on every mesh'}."]
    print("\n".join(cmp_lines))

    elapsed = time.perf_counter() - t_start
    footer = f"\nRun time {elapsed:.1f} s (wall clock)."
    print(footer)

    os.makedirs(os.path.dirname(os.path.abspath(args.out)), exist_ok=True)
    with open(args.out, "w") as fh:
        fh.write("# Loop interpolation beside the papers\n\n")
        fh.write("Meshes reduced to the vertices used by faces and scaled so that the largest side of the bounding "
                 "box is 1; '1e-3' and '1e-6' are absolute errors in that unit box.\n\n")
        fh.write("\n".join(rows + legend + notes_md + cmp_lines) + "\n" + footer + "\n")
    print(f"written to {args.out}")

    # --- plot -------------------------------------------------------------
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    colors = {"PIA": "tab:blue", "WPIA": "tab:orange", "GS_PIA": "tab:green", "AUTO": "tab:red"}
    fig, axes = plt.subplots(2, 2, figsize=(12, 9))
    for ax, (name, kind) in zip(axes.ravel(), MESHES):
        res = [r for r in results if r["name"] == name]
        for r in res:
            style = "-" if r["rule"] == "HOPPE" or kind == "closed" else "--"
            for m in METHODS:
                h = histories[r["tag"]][m]
                ax.semilogy(np.arange(len(h)), h, style, color=colors[m], lw=1.4)
        d = res[0]["diag"]
        for target in TARGETS:
            ax.axhline(target / d, color="0.5", lw=0.8, ls=":")
            ax.text(88, target / d * 1.4, f"{target:g} in the unit box", fontsize=8, color="0.35", ha="right")
        ax.set_title(f"{name} ({kind}, {res[0]['n']:,} vertices)")
        ax.set_xlabel("iteration (0: cage = mesh)")
        ax.set_ylabel("max error / bbox diagonal")
        ax.set_xlim(0, 90)
        ax.set_ylim(1e-12, 0.1)
        ax.grid(True, which="major", alpha=0.3)
    from matplotlib.lines import Line2D
    handles = [Line2D([], [], color=colors[m], lw=2, label=LABEL[m]) for m in METHODS]
    handles += [Line2D([], [], color="k", ls="-", label="closed mesh, or boundary rule HOPPE"),
                Line2D([], [], color="k", ls="--", label="boundary rule SMOOTH")]
    fig.legend(handles=handles, loc="lower center", ncol=6, fontsize=9, frameon=False)
    fig.suptitle("Loop limit-point interpolation: max error per iteration (meshes scaled to a unit bounding box)")
    fig.tight_layout(rect=(0, 0.04, 1, 1))
    os.makedirs(os.path.dirname(os.path.abspath(args.plot)), exist_ok=True)
    fig.savefig(args.plot, dpi=110)
    print(f"plot written to {args.plot}")


if __name__ == "__main__":
    main()
