# SPDX-License-Identifier: GPL-3.0-or-later
"""Which of the library's source files call functions defined in which
others, from the symbols of the objects a build made (nm): prints each
file's dependencies and any cycle among them; exits 1 on a cycle.

    /usr/bin/python3 tools/file_deps.py [build/cmake]"""
import os
import subprocess
import sys


def objects(build):
    folder = os.path.join(build, "CMakeFiles", "subdiv_pia.dir", "csrc", "src")
    return {name.rsplit(".", 1)[0]: os.path.join(folder, name) for name in sorted(os.listdir(folder))
            if name.endswith(".o")}


def symbols(path):
    defined, used = set(), set()
    for line in subprocess.run(["nm", path], capture_output=True, text=True, check=True).stdout.splitlines():
        parts = line.split()
        if len(parts) == 2 and parts[0] == "U":
            used.add(parts[1])
        elif len(parts) == 3 and parts[1] in "TDBRW":
            defined.add(parts[2])
    return defined, used


def cycles(graph):
    found, state, stack = [], {}, []

    def visit(node):
        state[node] = 1
        stack.append(node)
        for nxt in sorted(graph[node]):
            if state.get(nxt) == 1:
                found.append(stack[stack.index(nxt):] + [nxt])
            elif nxt not in state:
                visit(nxt)
        stack.pop()
        state[node] = 2

    for node in sorted(graph):
        if node not in state:
            visit(node)
    return found


def main():
    build = sys.argv[1] if len(sys.argv) > 1 else os.path.join("build", "cmake")
    table = {name: symbols(path) for name, path in objects(build).items()}
    owner = {sym: name for name, (defined, _) in table.items() for sym in defined}
    graph = {name: {owner[s] for s in used if s in owner and owner[s] != name} for name, (_, used) in table.items()}
    for name in sorted(graph):
        print(f"{name}: {' '.join(sorted(graph[name])) or '-'}")
    found = cycles(graph)
    for c in found:
        print("cycle: " + " -> ".join(c))
    if not found:
        print("no cycle")
    return 1 if found else 0


if __name__ == "__main__":
    sys.exit(main())
