# SPDX-License-Identifier: GPL-2.0-or-later
"""Run the Blender test suite inside Blender:

    blender -b --factory-startup --python-exit-code 1 --python tests/blender/run.py -- [pytest args]

Uses the built add-on (build/addon/subdiv_pia, or the folder containing
subdiv_pia named by SUBDIV_PIA_ADDON_DIR), registers it and runs pytest on
tests/blender. Exits with pytest's status (1 when no test ran).
"""

import os
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(os.path.dirname(HERE))


def main():
    addon_dir = os.path.abspath(os.environ.get("SUBDIV_PIA_ADDON_DIR")
                                or os.path.join(ROOT, "build", "addon"))
    if not os.path.isdir(os.path.join(addon_dir, "subdiv_pia")):
        print("run.py: no subdiv_pia package in %s (run `make build` first)" % addon_dir,
              file=sys.stderr)
        return 1
    sys.path.insert(0, addon_dir)
    os.environ["SUBDIV_PIA_ADDON_DIR"] = addon_dir  # for subprocess tests

    import pytest
    import subdiv_pia
    subdiv_pia.register()
    argv = sys.argv[sys.argv.index("--") + 1:] if "--" in sys.argv else []
    if not any(os.path.exists(a.split("::")[0]) for a in argv if not a.startswith("-")):
        argv = [HERE] + argv  # no test paths given: the whole Blender suite
    try:
        code = pytest.main(["-p", "no:cacheprovider", "-q", "--rootdir", ROOT] + argv)
    finally:
        try:
            subdiv_pia.unregister()
        except Exception:  # registration state after the last factory reset
            pass
    code = int(code)
    if code == 5:  # no tests collected
        code = 1
    return code


if __name__ == "__main__":
    sys.stdout.flush()
    sys.exit(main())
