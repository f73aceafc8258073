#!/usr/bin/env python3
"""Finds two-file import circles between the modules of a Python package (module A imports B and
B imports A), the Python side of scripts/check-module-cycles.py.

Plain python3 (the standard library's `ast`), nothing imported from the package. What counts as
"A imports B" (an edge A -> B): every `import` and `from … import …` in A's code, at any depth
(a lazy import inside a function is a dependency too), resolved to a file of the package:
`from .x import y` / `from ..x import y` relative to A's package, `koopbridge.x.y` absolute;
`from pkg import name` is an edge to the submodule `pkg/name.py` when that file exists, else to
`pkg/__init__.py`. An edge to one's own package `__init__.py` counts only when A uses a name
that `__init__.py` defines itself (an `__init__` that only re-exports is a facade, as a mod.rs
that only declares its children): here, any `from . import name` whose `name` is not a submodule.
Imports under `if TYPE_CHECKING:` are skipped (they never run).

    python3 scripts/check-python-cycles.py [PACKAGE_DIR ...]   # default: adapters/python/python/koopbridge

A circle is a pair of files A != B with A -> B and B -> A; each is printed with one line for each
direction. Exit status 1 when any exists.
"""

from __future__ import annotations

import ast
import pathlib
import sys


def module_name(root: pathlib.Path, path: pathlib.Path) -> str:
    """The dotted name of `path` in the package rooted at `root` (a package is its __init__)."""
    rel = path.relative_to(root.parent).with_suffix("")
    parts = list(rel.parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def type_checking_lines(tree: ast.AST) -> set[int]:
    """Lines of the statements under `if TYPE_CHECKING:` (or `typing.TYPE_CHECKING`)."""
    lines: set[int] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.If):
            t = node.test
            name = t.id if isinstance(t, ast.Name) else t.attr if isinstance(t, ast.Attribute) else ""
            if name == "TYPE_CHECKING":
                for stmt in node.body:
                    for sub in ast.walk(stmt):
                        if hasattr(sub, "lineno"):
                            lines.add(sub.lineno)
    return lines


def from_module(node: ast.ImportFrom, package: str) -> str:
    """The dotted module a `from … import …` in `package` names (relative levels resolved)."""
    if not node.level:
        return node.module or ""
    base = package.split(".")
    base = base[: len(base) - (node.level - 1)] if node.level > 1 else base
    return ".".join(base + ([node.module] if node.module else []))


def edges_of(root: pathlib.Path, path: pathlib.Path, files: dict[str, pathlib.Path], exports: dict[str, dict[str, str]]) -> list[tuple[str, int, str]]:
    """(target module, line, the import as written) for every import of `path` into the package."""
    me = module_name(root, path)
    package = me if path.name == "__init__.py" else me.rpartition(".")[0]
    tree = ast.parse(path.read_text(), str(path))
    skip = type_checking_lines(tree)
    out: list[tuple[str, int, str]] = []

    def target(mod: str) -> str | None:
        return mod if mod in files else None

    for node in ast.walk(tree):
        if getattr(node, "lineno", None) in skip:
            continue
        if isinstance(node, ast.Import):
            for a in node.names:
                name = a.name
                while name and not target(name):
                    name = name.rpartition(".")[0]
                if name:
                    out.append((name, node.lineno, f"import {a.name}"))
        elif isinstance(node, ast.ImportFrom):
            mod = from_module(node, package)
            if not target(mod):
                continue
            written = f"from {'.' * node.level}{node.module or ''} import {', '.join(a.name for a in node.names)}"
            for a in node.names:
                sub = f"{mod}.{a.name}"
                if target(sub):
                    out.append((sub, node.lineno, written))
                elif files[mod].name == "__init__.py":
                    # A name a package's __init__ only re-exports belongs to the module that
                    # defines it (outside the package: no edge).
                    if mod not in exports:
                        exports[mod] = reexports(files[mod], mod, files)
                    src = exports[mod].get(a.name, mod)
                    if src:
                        out.append((src, node.lineno, written))
                else:
                    out.append((mod, node.lineno, written))
    return [(t, line, w) for t, line, w in out if t != me]


def reexports(init: pathlib.Path, package: str, files: dict[str, pathlib.Path]) -> dict[str, str]:
    """The names the package `__init__` at `init` imports from elsewhere: name -> the package
    module it comes from, or "" when it comes from outside the package's .py files."""
    out: dict[str, str] = {}
    for node in ast.parse(init.read_text()).body:
        if isinstance(node, ast.ImportFrom):
            mod = from_module(node, package)
            for a in node.names:
                sub = f"{mod}.{a.name}"
                out[a.asname or a.name] = sub if sub in files else (mod if mod in files else "")
    return out


def circles(root: pathlib.Path) -> list[str]:
    """The two-file circles of the package at `root`, one message each."""
    files = {module_name(root, p): p for p in sorted(root.rglob("*.py"))}
    edges: dict[tuple[str, str], tuple[int, str]] = {}
    exports: dict[str, dict[str, str]] = {}  # each __init__'s re-exports, parsed once
    for mod, path in files.items():
        for t, line, written in edges_of(root, path, files, exports):
            edges.setdefault((mod, t), (line, written))
    found = []
    for (a, b), (line, written) in sorted(edges.items()):
        if a < b and (b, a) in edges:
            line2, written2 = edges[(b, a)]
            found.append(f"{files[a]}:{line} `{written}` -> {b}\n  {files[b]}:{line2} `{written2}` -> {a}")
    return found


def main(argv: list[str]) -> int:
    roots = [pathlib.Path(a) for a in argv] or [pathlib.Path("adapters/python/python/koopbridge")]
    bad = 0
    for root in roots:
        n_files = len(list(root.rglob("*.py")))
        found = circles(root)
        print(f"{root}: {n_files} module files, {len(found)} two-file circle(s)")
        for f in found:
            print("  " + f)
        bad += len(found)
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
