"""The import graph of ``perturb``: circles, upward imports, lazy imports, private names.

A static read (``ast``; nothing is imported) of every module under ``perturb/``. It prints

- the number of internal import statements, and how many sit inside functions ("lazy");
- the import circles between modules (strongly connected components of the module graph,
  module-level and lazy imports both counted: a lazy import hides a circle, it does not remove
  it);
- every import that points upwards in the layer table of ``docs/architecture.md``;
- every import of another module's private (``_name``) name;
- the largest files and functions.

Run ``python tools/import_graph.py`` (``--json`` for a machine-readable dump). It is the
measure of the redesign: run it before and after a change of structure.
"""

from __future__ import annotations

import argparse
import ast
import json
import sys
from collections import defaultdict
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = "perturb"

#: Layer of each module prefix, lowest first; a module may import its own layer or lower ones.
#: The most specific prefix wins.  Mirrors the layer drawing of docs/architecture.md.
LAYERS: dict[str, int] = {
    "perturb.errors": 0,
    "perturb.progress": 0,
    "perturb.atomic": 0,
    "perturb.checks": 0,
    "perturb.model": 1,
    "perturb.fourier": 1,
    "perturb.printing": 1,
    "perturb.approximation": 2,
    "perturb.response": 2,
    "perturb.comparison": 2,
    "perturb.numeric": 3,
    "perturb.simulate": 4,
    "perturb.methods": 4,
    "perturb.io": 5,
    "perturb.report": 5,
    "perturb.seeds": 6,
    "perturb.solve": 7,
    "perturb.auto": 8,
    "perturb.apps": 9,
    "perturb": 10,  # the package's __init__ re-exports the front doors
}

#: Pairs of sibling layers that must not import each other (same layer number).
FORBIDDEN_SIBLINGS = [
    ("perturb.methods", "perturb.simulate"),
    ("perturb.simulate", "perturb.methods"),
    ("perturb.methods", "perturb.numeric"),
]

#: Lower modules a layer must still not import: the reference solvers never import the
#: approximations they judge (the ``forbidden`` contracts of pyproject.toml).
FORBIDDEN_TARGETS = {
    "perturb.simulate": (
        "perturb.numeric.amplitude",
        "perturb.numeric.residual",
        "perturb.numeric.harmonic_balance",
        "perturb.numeric.compile",
    ),
}


def module_name(path: Path) -> str:
    rel = path.relative_to(ROOT).with_suffix("")
    parts = list(rel.parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def layer_of(module: str) -> tuple[str, int]:
    best = ""
    for prefix in LAYERS:
        if (module == prefix or module.startswith(prefix + ".")) and len(prefix) > len(best):
            best = prefix
    return best, LAYERS.get(best, -1)


class _Imports(ast.NodeVisitor):
    def __init__(self, module: str, is_package: bool, known: set[str]) -> None:
        self.module, self.is_package, self.known = module, is_package, known
        self.depth = 0
        self.rows: list[dict] = []

    def _resolve(self, level: int, target: str | None) -> str:
        if level == 0:
            return target or ""
        base = self.module.split(".")
        if not self.is_package:
            base = base[:-1]
        base = base[: len(base) - (level - 1)] if level > 1 else base
        return ".".join(base + ([target] if target else []))

    def _add(self, node: ast.AST, target: str, names: list[str]) -> None:
        if not (target == PACKAGE or target.startswith(PACKAGE + ".")):
            return
        for name in names or [""]:
            full = f"{target}.{name}" if name else target
            mod = full if full in self.known else target
            self.rows.append(
                {
                    "line": node.lineno,
                    "target": mod,
                    "name": "" if mod == full else name,
                    "lazy": self.depth > 0,
                }
            )

    def visit_FunctionDef(self, node: ast.FunctionDef) -> None:
        self.depth += 1
        self.generic_visit(node)
        self.depth -= 1

    visit_AsyncFunctionDef = visit_FunctionDef  # noqa: N815

    def visit_Import(self, node: ast.Import) -> None:
        for alias in node.names:
            self._add(node, alias.name, [])

    def visit_ImportFrom(self, node: ast.ImportFrom) -> None:
        target = self._resolve(node.level, node.module)
        self._add(node, target, [a.name for a in node.names])


def read_graph() -> tuple[dict[str, list[dict]], dict[str, Path]]:
    files = sorted((ROOT / PACKAGE).rglob("*.py"))
    paths = {module_name(p): p for p in files}
    known = set(paths)
    graph: dict[str, list[dict]] = {}
    for mod, path in paths.items():
        visitor = _Imports(mod, path.name == "__init__.py", known)
        visitor.visit(ast.parse(path.read_text(encoding="utf-8")))
        graph[mod] = [r for r in visitor.rows if r["target"] != mod]
    return graph, paths


def circles(graph: dict[str, list[dict]]) -> list[list[str]]:
    """Strongly connected components with more than one module (Tarjan, iterative)."""
    edges = {
        m: sorted({r["target"] for r in rows if r["target"] in graph}) for m, rows in graph.items()
    }
    # the package __init__ re-exports everything: leave it out, or every module is in a circle
    edges.pop(PACKAGE, None)
    for m in edges:
        edges[m] = [t for t in edges[m] if t != PACKAGE]
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    on_stack: set[str] = set()
    stack: list[str] = []
    out: list[list[str]] = []
    counter = 0
    for root in edges:
        if root in index:
            continue
        work = [(root, iter(edges[root]))]
        index[root] = low[root] = counter
        counter += 1
        stack.append(root)
        on_stack.add(root)
        while work:
            node, it = work[-1]
            child = next(it, None)
            if child is not None:
                if child not in index:
                    index[child] = low[child] = counter
                    counter += 1
                    stack.append(child)
                    on_stack.add(child)
                    work.append((child, iter(edges.get(child, []))))
                elif child in on_stack:
                    low[node] = min(low[node], index[child])
                continue
            work.pop()
            if work:
                parent = work[-1][0]
                low[parent] = min(low[parent], low[node])
            if low[node] == index[node]:
                comp = []
                while True:
                    top = stack.pop()
                    on_stack.discard(top)
                    comp.append(top)
                    if top == node:
                        break
                if len(comp) > 1:
                    out.append(sorted(comp))
    return out


def upward(graph: dict[str, list[dict]]) -> list[tuple[str, int, str, bool]]:
    rows = []
    for mod, imports in graph.items():
        if mod == PACKAGE:
            continue
        src_prefix, src = layer_of(mod)
        for r in imports:
            dst_prefix, dst = layer_of(r["target"])
            if r["target"] == PACKAGE:
                continue
            bad = dst > src or (src_prefix, dst_prefix) in FORBIDDEN_SIBLINGS
            bad = bad or any(
                r["target"] == f or r["target"].startswith(f + ".")
                for f in FORBIDDEN_TARGETS.get(src_prefix, ())
            )
            if bad:
                rows.append((mod, r["line"], r["target"], r["lazy"]))
    return rows


def private_imports(graph: dict[str, list[dict]]) -> list[tuple[str, int, str, str]]:
    return [
        (mod, r["line"], r["target"], r["name"])
        for mod, imports in graph.items()
        for r in imports
        if r["name"].startswith("_") and not r["name"].startswith("__")
    ]


def sizes(paths: dict[str, Path]) -> tuple[list[tuple[str, int]], list[tuple[str, str, int]]]:
    files, funcs = [], []
    for mod, path in paths.items():
        text = path.read_text(encoding="utf-8")
        files.append((mod, text.count("\n") + 1))
        for node in ast.walk(ast.parse(text)):
            if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef):
                funcs.append((mod, node.name, node.end_lineno - node.lineno + 1))
    files.sort(key=lambda r: -r[1])
    funcs.sort(key=lambda r: -r[2])
    return files, funcs


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--json", action="store_true", help="print one JSON object")
    parser.add_argument("--top", type=int, default=12, help="rows of the size tables")
    args = parser.parse_args(argv)
    graph, paths = read_graph()
    # statements, not names: ``from .x import a, b`` is one import
    statements = {(m, r["line"]): r["lazy"] for m, rows in graph.items() for r in rows}
    total, lazy = len(statements), sum(statements.values())
    circ = circles(graph)
    up = sorted(set(upward(graph)))
    priv = private_imports(graph)
    files, funcs = sizes(paths)
    summary = {
        "modules": len(graph),
        "internal_imports": total,
        "lazy_imports": lazy,
        "circles": circ,
        "upward_imports": [
            {"module": m, "line": ln, "imports": t, "lazy": lz} for m, ln, t, lz in up
        ],
        "private_imports": [
            {"module": m, "line": ln, "from": t, "name": n} for m, ln, t, n in priv
        ],
        "functions_over_100_lines": sum(n > 100 for *_, n in funcs),
        "functions_over_200_lines": sum(n > 200 for *_, n in funcs),
        "largest_files": files[: args.top],
        "largest_functions": funcs[: args.top],
    }
    if args.json:
        json.dump(summary, sys.stdout, indent=1)
        print()
        return 0
    print(f"modules {len(graph)}, internal imports {total}, inside functions {lazy}")
    print(f"circles: {len(circ)}")
    for c in circ:
        print("  " + " <-> ".join(c))
    print(f"upward imports (against docs/architecture.md): {len(up)}")
    by_pair: dict[tuple[str, str], list[str]] = defaultdict(list)
    for m, ln, t, lz in up:
        by_pair[(m, t)].append(f"{ln}{'*' if lz else ''}")
    print("  (statements; the same line importing two names counts once)")
    for (m, t), lines in sorted(by_pair.items()):
        print(f"  {m} -> {t}  (line {', '.join(lines)}; * inside a function)")
    print(f"private names imported across modules: {len(priv)}")
    print(
        f"functions over 100 lines: {summary['functions_over_100_lines']}, "
        f"over 200: {summary['functions_over_200_lines']}"
    )
    print("largest files:")
    for m, n in files[: args.top]:
        print(f"  {n:6d}  {m}")
    print("largest functions:")
    for m, f, n in funcs[: args.top]:
        print(f"  {n:6d}  {m}.{f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
