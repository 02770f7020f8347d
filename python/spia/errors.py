# SPDX-License-Identifier: GPL-3.0-or-later
"""The errors the binding raises, and the library's result codes by name.

A call that the library refuses or that fails raises :class:`PiaError` (or
:class:`PiaCancelled` when a progress callback asked to stop), with the
name of the code and the library's own message."""

_RESULT_NAMES = {
    0: "OK", 1: "MAX_ITERATIONS", 2: "STAGNATED",
    -1: "INVALID_ARGUMENT", -2: "EMPTY_MESH", -3: "FACE_SIZE", -4: "INDEX_RANGE",
    -5: "NONFINITE", -6: "DEGENERATE_FACE", -7: "TOPOLOGY", -8: "OUT_OF_MEMORY",
    -9: "CANCELLED", -10: "DIVERGED", -11: "INTERNAL",
}
_STATUS_OF_RESULT = {0: "CONVERGED", 1: "MAX_ITERATIONS", 2: "STAGNATED"}


class PiaError(Exception):
    """The library refused the input or failed; ``code`` names why."""

    def __init__(self, code, message, index=-1):
        super().__init__(message)
        self.code = code
        self.message = message
        self.index = index


class PiaCancelled(PiaError):
    """The progress callback asked to stop."""


def _raise(code, status):
    name = _RESULT_NAMES.get(code, str(code))
    message = status.message.decode("utf-8", "replace") or name
    cls = PiaCancelled if name == "CANCELLED" else PiaError
    raise cls(name, message, status.index)
