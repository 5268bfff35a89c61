#!/usr/bin/env python3
"""Folder-level include graph of the library (issue 26): which top-level folder includes which.

A file in src/<a>/ or include/frostvdb/<a>/ that includes <frostvdb/<b>/...> (or a relative
header resolving to folder b) makes an edge a -> b. Prints every edge with the count of includes
and one example; exits 1 when the graph has a cycle (listing the cycles' folders).

    python3 scripts/include_cycles.py            # edges, then "no cycles" or the cycles
    python3 scripts/include_cycles.py --quiet    # only the cycles (for CI / tests)
    python3 scripts/include_cycles.py --quiet --allow ice:shell   # a known cycle, tolerated

--allow A:B (repeatable) drops the edges between folders A and B (both directions) before the
cycle search: a cycle being taken apart in other work, so that the check still catches new ones.
"""
import os
import re
import sys
from collections import defaultdict

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
INCLUDE = re.compile(r'^\s*#\s*include\s*[<"]frostvdb/([A-Za-z0-9_]+)/[^>"]+[>"]', re.M)


def folder_of(path):
    rel = os.path.relpath(path, ROOT).split(os.sep)
    if rel[0] == "src" and len(rel) > 2:
        return rel[1]
    if rel[:2] == ["include", "frostvdb"] and len(rel) > 3:
        return rel[2]
    return None


def edges():
    out = defaultdict(list)
    for top in ("src", os.path.join("include", "frostvdb")):
        for dirpath, _, files in os.walk(os.path.join(ROOT, top)):
            for fn in files:
                if not fn.endswith((".h", ".hpp", ".cpp")):
                    continue
                path = os.path.join(dirpath, fn)
                a = folder_of(path)
                if a is None:
                    continue
                with open(path, encoding="utf-8", errors="replace") as f:
                    text = f.read()
                for b in INCLUDE.findall(text):
                    if b != a:
                        out[(a, b)].append(os.path.relpath(path, ROOT))
    return out


def cycles(graph):
    """Strongly connected components with more than one folder (Tarjan)."""
    index, low, stack, on, result = {}, {}, [], set(), []
    counter = [0]

    def visit(v):
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on.add(v)
        for w in sorted(graph.get(v, ())):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                result.append(sorted(comp))

    nodes = set(graph) | {w for ws in graph.values() for w in ws}
    for v in sorted(nodes):
        if v not in index:
            visit(v)
    return result


def main():
    args = sys.argv[1:]
    quiet = "--quiet" in args
    allowed = set()
    for i, a in enumerate(args):
        if a == "--allow" and i + 1 < len(args):
            x, _, y = args[i + 1].partition(":")
            allowed |= {(x, y), (y, x)}
    e = edges()
    e = {k: v for k, v in e.items() if k not in allowed}
    graph = defaultdict(set)
    for (a, b) in e:
        graph[a].add(b)
    if not quiet:
        for (a, b), files in sorted(e.items()):
            print(f"{a:10s} -> {b:10s} {len(files):3d}  e.g. {files[0]}")
    cyc = cycles(graph)
    for c in cyc:
        # name the edges inside the cycle, with an example file each
        inner = [f"{a}->{b} ({e[(a, b)][0]})" for (a, b) in sorted(e) if a in c and b in c]
        print("cycle: " + " <-> ".join(c) + ": " + ", ".join(inner))
    if cyc:
        sys.exit(1)
    if not quiet:
        print("no cycles")


if __name__ == "__main__":
    main()
