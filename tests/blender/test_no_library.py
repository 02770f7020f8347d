# SPDX-License-Identifier: GPL-3.0-or-later
"""Without a loadable native library (SUBDIV_PIA_LIBRARY naming a missing or
a bogus file, in a Blender of its own) the panel says what is needed instead
of its settings, and the operator and the script API refuse, creating
nothing."""

import json
import os
import subprocess

import pytest

import subdiv_pia
from test_api_cli import cli_command

HERE = os.path.dirname(os.path.abspath(__file__))
FOLDER = os.path.dirname(os.path.abspath(subdiv_pia.__file__))


def run_without_library(library):
    command = cli_command()
    command[command.index("--") - 1] = os.path.join(HERE, "no_library.py")  # the script, not cli.py
    env = dict(os.environ, SUBDIV_PIA_LIBRARY=library)
    result = subprocess.run(command + [FOLDER], capture_output=True, text=True, timeout=120, env=env)
    assert result.returncode == 0, result.stdout + result.stderr
    lines = [line for line in result.stdout.splitlines() if line.startswith("RESULT ")]
    assert len(lines) == 1, result.stdout + result.stderr
    return json.loads(lines[0][len("RESULT "):])


@pytest.mark.parametrize("kind", ("missing", "bogus"))
def test_no_library_panel_says_why_and_operator_cancels(tmp_path, kind):
    library = str(tmp_path / "libsubdiv_pia.so")
    if kind == "bogus":
        with open(library, "w") as f:
            f.write("not a shared library\n")
    out = run_without_library(library)
    assert out["package"] == FOLDER
    assert not out["available"]
    head = "The library that SUBDIV_PIA_LIBRARY names is " + (
        "missing" if kind == "missing" else "not a library for this system")
    assert out["load_error"].startswith(head), out["load_error"]
    assert library in out["load_error"]

    labels = [text for what, text in out["log"] if what == "label"]
    assert labels[0] == "Native library not loaded:"
    assert " ".join(labels[1:]).startswith(head), labels
    assert library in "".join(labels), labels
    assert not [entry for entry in out["log"] if entry[0] != "label"], out["log"]  # no settings, no button

    assert out["operator"] is None and out["operator_error"], out
    assert "library not loaded: " + head in out["operator_error"], out["operator_error"]
    assert head in out["api_error"], out["api_error"]
    assert out["counts_after"] == out["counts_before"]
    assert out["active"] == out["source"]
