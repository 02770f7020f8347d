# SPDX-License-Identifier: GPL-3.0-or-later
"""The add-on's modules import one another without circles, and so do the
binding's (python/spia), whose __init__ none of them imports; the binding
(and addon/native.py that stands for it) imports no Blender module and
nothing of the add-on's.  The scripts (bench/, tools/, tests/, setup.py),
which import one another by their file names, have no circle either.

Read from the sources with ast: nothing is imported, Blender is not needed.
Imports inside functions count as much as those at the top of a module.
"""

import ast
import os

import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
ADDON = os.path.join(ROOT, "addon")
BINDING = os.path.join(ROOT, "python", "spia")
BINDING_PACKAGE = "spia"
PACKAGE = "subdiv_pia"  # the add-on's name once installed (setup.py build, the packages)
# The folders of scripts that import one another by file name (each puts the
# folders it needs on sys.path); "." is setup.py's.
SCRIPT_FOLDERS = ["bench", "tools", os.path.join("tests", "python"), os.path.join("tests", "package"),
                  os.path.join("tests", "blender"), os.path.join("tests", "window"), "."]
PACKAGE_MODULE = "__init__"
BLENDER_MODULES = {"bpy", "bmesh", "mathutils", "bpy_extras", "bl_math", "gpu", "gpu_extras", "blf", "aud",
                   "idprop", "freestyle", "imbuf", "bgl"}


def _sources(folder):
    """{module name: path} of the .py files directly in folder."""
    return {name[:-3]: os.path.join(folder, name) for name in sorted(os.listdir(folder))
            if name.endswith(".py")}


def _parse(path):
    with open(path, encoding="utf-8") as f:
        return ast.parse(f.read(), filename=path)


def _imports(tree):
    """(line, level, module or None, names) of every import statement
    anywhere in tree: `import a.b` gives (line, 0, "a.b", ()), `from .x import
    y` (line, 1, "x", ("y",)), `from . import x` (line, 1, None, ("x",))."""
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for alias in node.names:
                yield node.lineno, 0, alias.name, ()
        elif isinstance(node, ast.ImportFrom):
            yield node.lineno, node.level, node.module, tuple(alias.name for alias in node.names)


def _package_targets(level, module, names, modules, package=PACKAGE):
    """The modules of the package (names of `modules`) that one import
    statement in one of them loads: a submodule named after the package
    or the dot, else the package itself (__init__) for names it defines."""
    if level == 0:
        parts = (module or "").split(".")
        if parts[0] != package:
            return set()
        if len(parts) > 1:
            return {parts[1] if parts[1] in modules else PACKAGE_MODULE}
        if names:  # from subdiv_pia import x, y
            return {n if n in modules else PACKAGE_MODULE for n in names}
        return {PACKAGE_MODULE}  # import subdiv_pia
    if level > 1:
        raise AssertionError("an import reaches above the add-on's package (level %d)" % level)
    if module:
        head = module.split(".")[0]
        return {head if head in modules else PACKAGE_MODULE}
    return {n if n in modules else PACKAGE_MODULE for n in names}


def import_graph(folder, package=PACKAGE):
    """{module: {module it imports: first line of such an import}} for the
    package whose modules are the .py files in folder."""
    sources = _sources(folder)
    graph = {}
    for name, path in sources.items():
        edges = graph.setdefault(name, {})
        for line, level, module, names in _imports(_parse(path)):
            for target in _package_targets(level, module, names, sources, package):
                if target != name:
                    edges.setdefault(target, line)
    return graph


def find_cycle(graph):
    """A list [a, b, ..., a] of modules that import one another in a circle, or None."""
    state = {}  # module -> 1 while on the path, 2 once done
    path = []

    def visit(node):
        state[node] = 1
        path.append(node)
        for nxt in sorted(graph.get(node, ())):
            if state.get(nxt) == 1:
                return path[path.index(nxt):] + [nxt]
            if nxt not in state:
                found = visit(nxt)
                if found:
                    return found
        path.pop()
        state[node] = 2
        return None

    for node in sorted(graph):
        if node not in state:
            found = visit(node)
            if found:
                return found
    return None


def describe(cycle, graph):
    return " -> ".join(cycle) + "  (" + "; ".join(
        "%s.py:%d imports %s" % (a, graph[a][b], b) for a, b in zip(cycle, cycle[1:])) + ")"


def test_addon_modules_import_one_another_without_circles():
    graph = import_graph(ADDON)
    assert {"api", "live", "native"} <= set(graph)
    cycle = find_cycle(graph)
    assert cycle is None, "import circle in addon/: " + describe(cycle, graph)


def test_binding_modules_import_one_another_without_circles():
    graph = import_graph(BINDING, BINDING_PACKAGE)
    assert {PACKAGE_MODULE, "library", "header", "mesh", "interpolation", "usd", "fitting"} <= set(graph)
    cycle = find_cycle(graph)
    assert cycle is None, "import circle in python/spia/: " + describe(cycle, graph)


def test_the_binding_package_is_imported_by_none_of_its_modules():
    # __init__ gathers the modules' names: a module that imported it would
    # be imported before the names it needs were there.
    graph = import_graph(BINDING, BINDING_PACKAGE)
    users = sorted(m for m in graph if PACKAGE_MODULE in graph[m])
    assert not users, "modules of python/spia import its __init__: %s" % users
    assert set(graph) - {PACKAGE_MODULE} <= set(graph[PACKAGE_MODULE]), "modules __init__ does not gather"


def test_the_facade_is_imported_by_no_module_it_names():
    # api names what scripts use from the others: none of those may need it.
    graph = import_graph(ADDON)
    below = _reachable(graph, "api")
    users = sorted(m for m in below if "api" in graph[m])
    assert not users, "modules api imports (directly or not) import api: %s" % users


def _reachable(graph, start):
    seen, todo = set(), [start]
    while todo:
        for nxt in graph.get(todo.pop(), ()):
            if nxt not in seen:
                seen.add(nxt)
                todo.append(nxt)
    return seen


def _foreign_imports(path, allowed_relative):
    """What the file at path imports of Blender or of the add-on: a list of
    "file:line name"."""
    found = []
    for line, level, module, names in _imports(_parse(path)):
        where = "%s:%d" % (os.path.relpath(path, ROOT), line)
        if level:
            if not allowed_relative:
                found.append("%s from %s%s import %s" % (where, "." * level, module or "", ", ".join(names)))
            continue
        top = (module or "").split(".")[0]
        if top in BLENDER_MODULES or top == PACKAGE:
            found.append("%s %s" % (where, module))
    return found


def test_the_binding_imports_no_blender_and_nothing_of_the_addon():
    paths = [os.path.join(d, n) for d, _dirs, files in os.walk(BINDING) for n in files if n.endswith(".py")]
    assert paths
    found = [f for path in sorted(paths) for f in _foreign_imports(path, allowed_relative=True)]
    # addon/native.py is the binding inside the add-on: no relative imports either.
    found += _foreign_imports(os.path.join(ADDON, "native.py"), allowed_relative=False)
    assert not found, "the binding imports Blender or the add-on: %s" % found


def test_a_circle_is_found_and_named(tmp_path):
    # Imports inside functions, `from . import x`, `from .x import y` and
    # absolute imports of the package all count.
    files = {
        "__init__.py": "from . import a\n",
        "a.py": "import os\nfrom .b import thing\n",
        "b.py": "def later():\n    import subdiv_pia.c\n",
        "c.py": "from subdiv_pia import a\n",
        "d.py": "from . import interpolate\n",
    }
    for name, text in files.items():
        (tmp_path / name).write_text(text)
    graph = import_graph(str(tmp_path))
    assert graph["d"] == {PACKAGE_MODULE: 1}
    cycle = find_cycle(graph)
    assert cycle == ["a", "b", "c", "a"], cycle
    assert "b.py:2 imports c" in describe(cycle, graph)
    (tmp_path / "c.py").write_text("import subdiv_pia_other\n")
    assert find_cycle(import_graph(str(tmp_path))) is None


@pytest.mark.parametrize("text", ["import bpy\n", "def f():\n    from bmesh import ops\n",
                                  "import subdiv_pia.api\n"])
def test_a_blender_import_in_the_binding_is_found(tmp_path, text):
    path = tmp_path / "mod.py"
    path.write_text(text)
    assert _foreign_imports(str(path), allowed_relative=True)


def script_graph(root=ROOT, folders=SCRIPT_FOLDERS):
    """{script: {script it imports: first line of such an import}} over the
    .py files directly in `folders` (under root), named by their path
    without .py.  An import's first name is the file of that name in the
    importer's own folder, else in whichever of the other folders has one."""
    found = {folder: _sources(os.path.join(root, folder)) for folder in folders
             if os.path.isdir(os.path.join(root, folder))}
    graph = {}
    for folder, sources in found.items():
        for name, path in sources.items():
            edges = graph.setdefault(os.path.normpath(os.path.join(folder, name)), {})
            for line, level, module, _names in _imports(_parse(path)):
                head = (module or "").split(".")[0]
                if level or not head:
                    continue
                homes = [folder] if head in sources else [f for f in found if head in found[f]]
                for home in homes:
                    target = os.path.normpath(os.path.join(home, head))
                    if target != os.path.normpath(os.path.join(folder, name)):
                        edges.setdefault(target, line)
    return graph


def test_scripts_import_one_another_without_circles():
    graph = script_graph()
    assert {"bench/bench_fit", "bench/fit_cases", "tools/package", "tests/package/dist", "setup"} <= set(graph)
    assert "tools/package" in graph["tests/package/dist"] and "bench/meshes" in graph["bench/bench_scale"]
    cycle = find_cycle(graph)
    assert cycle is None, "import circle among the scripts: " + describe(cycle, graph)


def test_a_circle_among_scripts_in_two_folders_is_found(tmp_path):
    for folder, files in {"bench": {"a.py": "import sys\nimport b\n", "b.py": "def f():\n    import helper\n"},
                          "tools": {"helper.py": "import os\nfrom a import thing\n", "b.py": ""}}.items():
        (tmp_path / folder).mkdir()
        for name, text in files.items():
            (tmp_path / folder / name).write_text(text)
    graph = script_graph(str(tmp_path), ["bench", "tools"])
    assert graph["bench/b"] == {"tools/helper": 2}  # its own folder's b, not tools/b
    cycle = find_cycle(graph)
    assert cycle == ["bench/a", "bench/b", "tools/helper", "bench/a"], cycle
    (tmp_path / "tools" / "helper.py").write_text("import os\n")
    assert find_cycle(script_graph(str(tmp_path), ["bench", "tools"])) is None
