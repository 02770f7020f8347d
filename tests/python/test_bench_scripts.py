# SPDX-License-Identifier: GPL-3.0-or-later
"""bench/ holds nothing that nothing runs, and docs/benchmarks.md tells each
benchmark the same way.

- Every script in bench/ is named (bench/NAME.py) on a page of the manual,
  in the README or in the Makefile, or is imported by one that is, or by
  the scripts make test runs (tests/, tools/); every C or C++ file there is
  built by bench/CMakeLists.txt or the Makefile, and every program that
  builds, by a make target.
- docs/benchmarks.md has a section a benchmark (its pictures aside), each
  with its command, what it measures and its latest results as a table
  with the machine and the date.

Read from the sources: nothing is run.
"""
import os
import re

from test_layering import ROOT, script_graph

BENCH = os.path.join(ROOT, "bench")
BENCHMARKS = os.path.join(ROOT, "docs", "benchmarks.md")
NOT_BENCHMARKS = ("Pictures",)  # sections of benchmarks.md that list no benchmark


def _read(*parts):
    with open(os.path.join(ROOT, *parts), encoding="utf-8") as f:
        return f.read()


def _manual_and_makefile():
    docs = os.path.join(ROOT, "docs")
    pages = ["README.md", "Makefile"] + [os.path.join("docs", n) for n in sorted(os.listdir(docs))
                                         if n.endswith(".md")]
    return "\n".join(_read(p) for p in pages)


def unreached_scripts(graph, named):
    """The bench scripts (graph keys under bench/) that neither `named` (bench
    scripts the manual or the Makefile names) nor the scripts outside bench/
    reach through their imports."""
    todo = [s for s in graph if not s.startswith("bench/")] + sorted(named)
    seen = set()
    while todo:
        script = todo.pop()
        if script in seen:
            continue
        seen.add(script)
        todo.extend(graph.get(script, ()))
    return sorted(s for s in graph if s.startswith("bench/") and s not in seen)


def test_every_bench_script_is_run_by_the_manual_or_a_make_target():
    graph = script_graph()
    named = {"bench/" + n for n in re.findall(r"\bbench/(\w+)\.py\b", _manual_and_makefile())}
    scripts = {"bench/" + n[:-3] for n in os.listdir(BENCH) if n.endswith(".py")}
    assert named <= scripts, "the manual or the Makefile names missing scripts: %s" % sorted(named - scripts)
    missing = unreached_scripts(graph, named)
    assert not missing, "nothing in the manual or the Makefile runs: %s" % missing


def test_a_script_nothing_runs_is_found():
    graph = {"bench/a": {"bench/helper": 1}, "bench/helper": {}, "bench/b": {"bench/c": 3}, "bench/c": {},
             "tests/python/test_x": {"bench/d": 2}, "bench/d": {}}
    assert unreached_scripts(graph, {"bench/a"}) == ["bench/b", "bench/c"]
    assert unreached_scripts(graph, {"bench/a", "bench/b"}) == []


def test_every_native_benchmark_is_built_and_run():
    cmake, makefile = _read("bench", "CMakeLists.txt"), _read("Makefile")
    sources = sorted(n for n in os.listdir(BENCH) if n.endswith((".c", ".cpp")))
    assert sources
    unbuilt = [n for n in sources if not re.search(r"\b%s\b" % re.escape(n), cmake + makefile)]
    assert not unbuilt, "bench sources nothing builds: %s" % unbuilt
    programs = re.findall(r"add_executable\((\w+)", cmake)
    assert programs
    unused = [p for p in programs if p not in makefile]
    assert not unused, "bench programs no make target builds: %s" % unused


def sections(text):
    """{heading: body} of the ## sections of a page (code blocks kept)."""
    parts = re.split(r"^## +(.+?)\s*$", text, flags=re.M)
    return dict(zip(parts[1::2], parts[2::2]))


def section_problems(heading, body):
    """What a benchmark's section lacks: its command, what it measures, its
    results as a table with the machine and the date."""
    problems = []
    if not re.search(r"^\*\*Command\*\*.*`(make bench[\w-]*|[^`]*\bbench/\w+\.(py|c))", body, re.M):
        problems.append("no **Command** naming a make target or a bench/ script")
    if not re.search(r"^\*\*Measures\*\*", body, re.M):
        problems.append("no **Measures**")
    if not re.search(r"^\*\*Latest results\*\*", body, re.M):
        problems.append("no **Latest results**")
    if not re.search(r"^\|.*\|\s*\n\|[\s:|-]*-[\s:|-]*\|\s*$", body, re.M):
        problems.append("no table")
    if not re.search(r"[Mm]achine:\s", body):
        problems.append("no machine")
    if not re.search(r"[Dd]ate:\s+\d{4}-\d\d-\d\d", body):
        problems.append("no date")
    return ["%s: %s" % (heading, p) for p in problems]


def test_every_benchmark_has_its_command_measure_and_results():
    found = sections(_read("docs", "benchmarks.md"))
    benchmarks = {h: b for h, b in found.items() if not h.startswith(NOT_BENCHMARKS)}
    assert len(benchmarks) >= 10
    problems = [p for h, b in benchmarks.items() for p in section_problems(h, b)]
    assert not problems, problems
    # Each make bench-* target has a section whose command names it.
    targets = set(re.findall(r"^(bench-[\w-]+):", _read("Makefile"), re.M))
    commands = " ".join(re.findall(r"^\*\*Command\*\*.*$", _read("docs", "benchmarks.md"), re.M))
    assert targets and not sorted(t for t in targets if "make %s" % t not in commands)


def test_a_section_without_results_is_found():
    good = ("**Command**: `make bench-x` (`bench/bench_x.py`)\n\n**Measures**: time.\n\n"
            "**Latest results** (machine: 2-core, date: 2026-12-07):\n\n| a | b |\n|---|---:|\n| 1 | 2 |\n")
    assert section_problems("x", good) == []
    assert section_problems("x", good.replace("| a | b |\n|---|---:|\n| 1 | 2 |\n", "none\n")) == ["x: no table"]
    assert section_problems("x", good.replace("2026-12-07", "lately")) == ["x: no date"]
    assert section_problems("x", good.replace("`make bench-x` (`bench/bench_x.py`)", "by hand")) == [
        "x: no **Command** naming a make target or a bench/ script"]
    assert section_problems("x", good.replace("`make bench-x` (`bench/bench_x.py`)",
                                              "`SPIA=1 python3 bench/bench_x.py --y`")) == []
    assert section_problems("x", good.replace("**Measures**", "Measures")) == ["x: no **Measures**"]
    assert section_problems("x", good.replace("machine: 2-core, ", "")) == ["x: no machine"]
