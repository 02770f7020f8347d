# SPDX-License-Identifier: GPL-3.0-or-later
"""One-line reports of a solve, a fit and a cleanup, for the status bar and
the command line.  Writes nothing."""

from . import cleanup
from .objects import REACHABLE_MAX_ERROR, UNREACHABLE_COUNT, UNREACHABLE_GROUP, cleanup_stats

FIT_NAMES = {'SURFACE': "Surface", 'VERTICES': "Vertices"}


def format_cleanup(obj):
    """'cleanup: merged 3 vertices, ...' for a cage made with cleanup, else ''."""
    stats = cleanup_stats(obj)
    return "" if stats is None else "cleanup: " + cleanup.format_stats(stats)


def format_fit_report(report, target_name):
    """One line for the status bar and the command line, for a fit."""
    b, a = report.before, report.after
    line = ("%s fit to '%s': mean distance %.2g (was %.2g), 95th percentile %.2g (was %.2g), "
            "max %.2g (was %.2g) of the scan's diagonal"
            % (FIT_NAMES.get(report.mode, report.mode), target_name, a.mean, b.mean, a.p95, b.p95,
               a.max, b.max))
    if report.mode == 'SURFACE':
        line += ", %d round%s" % (report.rounds, "" if report.rounds == 1 else "s")
    else:
        line += ", %d iterations" % report.iterations
    if a.ignored:
        line += "; %d of %d samples beyond the cut-off ignored" % (a.ignored, report.sample_count)
    if report.scan_point_count:
        s = report.scan_after
        line += ("; scan to surface: mean %.2g, 95th percentile %.2g, max %.2g, %.2g%% of the scan "
                 "farther than the cut-off" % (s.mean, s.p95, s.max, 100.0 * s.ignored / report.scan_point_count))
    if report.folded_after > 0 and report.sample_count:
        line += "; %.2g%% of the samples face away from the scan" % (100.0 * report.folded_after / report.sample_count)
    if report.status != 'CONVERGED':
        line += " (%s: %s)" % (report.status.lower().replace("_", " "), report.message)
    return line


def format_detail(obj):
    """What obj's detail levels came to ('' without them), from its custom
    properties (detail.store_detail)."""
    levels = int(obj.get("pia_fit_detail_levels", 0))
    if not levels:
        return ""
    line = ("%d detail level%s in Multires: the finest %.2g from the scan (mean), 95th percentile %.2g"
            % (levels, "" if levels == 1 else "s", float(obj["pia_fit_detail_mean"]),
               float(obj["pia_fit_detail_p95"])))
    if "pia_fit_detail_scan_mean" in obj:
        line += "; scan to it: mean %.2g, 95th percentile %.2g" % (float(obj["pia_fit_detail_scan_mean"]),
                                                                   float(obj["pia_fit_detail_scan_p95"]))
    return line


def report_converged(report):
    """True unless an interpolation or a fit stopped short of its tolerance."""
    return report.status == 'CONVERGED'


def format_unreachable(count, reachable_max_error):
    """What a result says of its unreachable vertices ('' when there are none)."""
    if not count:
        return ""
    return ("%d %s cannot be reached (in the vertex group '%s'); max error on the others %.3g of the "
            "bounding-box diagonal" % (count, "vertex" if count == 1 else "vertices", UNREACHABLE_GROUP,
                                       reachable_max_error))


def format_report(report):
    """One line for the status bar and the command line."""
    if report.converged:
        head = "Converged"
    elif report.status == 'STAGNATED':
        head = "Stagnated (tolerance not reached)"
    else:
        head = "Stopped at max iterations (tolerance not reached)"
    line = ("%s: %d iterations (%s), max error %.3g, mean error %.3g of the bounding-box diagonal"
            % (head, report.iterations, report.method,
               report.max_error_relative, report.mean_error_relative))
    if report.stage_iterations[0] > 0:
        line += "; boundary first: %d + %d iterations" % tuple(report.stage_iterations)
    unreachable = format_unreachable(report.unreachable_count, report.reachable_max_error_relative)
    if unreachable:  # the library's message says the same at more length
        line += "; " + unreachable
    elif not report.converged and report.message:
        line += " (%s)" % report.message
    return line


def status_line(obj):
    """(icon, text): the result of the run that made obj, in one line for
    the panel (converged and how close, or what went wrong); None when obj
    was not made by a run."""
    status = obj.get("pia_status")
    if status is None:
        return None
    fine = status == 'CONVERGED'
    if "pia_fit" in obj:
        text = "Fitted to '%s': mean distance %.2g of the scan's diagonal (was %.2g)" % (
            obj.get("pia_fit_target", "?"), float(obj.get("pia_fit_mean_after", 0.0)),
            float(obj.get("pia_fit_mean_before", 0.0)))
        if not fine:
            text = "%s: %s" % (status.capitalize().replace("_", " "), text)
        if obj.get("pia_fit_scan_not_painted"):
            fine, text = False, obj["pia_fit_scan_not_painted"]
        return ('CHECKMARK' if fine else 'ERROR'), text
    unreachable = int(obj.get(UNREACHABLE_COUNT, 0))
    if unreachable:
        return 'ERROR', "%d %s cannot be reached; max error on the others %.2g of the diagonal" % (
            unreachable, "vertex" if unreachable == 1 else "vertices", float(obj.get(REACHABLE_MAX_ERROR, 0.0)))
    error = float(obj.get("pia_max_error", 0.0))
    iterations = int(obj.get("pia_iterations", 0))
    if fine:
        return 'CHECKMARK', "Converged in %d iterations: max error %.2g of the diagonal" % (iterations, error)
    if status == 'STAGNATED':
        return 'ERROR', "Stagnated at max error %.2g of the diagonal: tolerance not reached" % error
    return 'ERROR', "Stopped after %d iterations at max error %.2g: tolerance not reached" % (iterations, error)
