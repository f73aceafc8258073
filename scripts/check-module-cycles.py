#!/usr/bin/env python3
"""Finds two-file import circles between the Rust modules of a crate (file A uses B, B uses A).

Plain python3, no dependencies, no compiler: a small lexer strips comments, strings and char
literals, then reads `use` declarations and `crate::…` / `super::…` / `self::…` paths in code.

What counts as "file A uses file B" (an edge A -> B):

1. A path in A's code (a `use` declaration or an inline path such as `super::cluster::names(…)`,
   `crate::scenario::Policy::Uniform`) is resolved the way rustc resolves it: `crate` is the crate
   root, `super` the parent of the (possibly inline) module the path stands in, `self` that
   module; in a `use`, a first segment naming a child module is relative to the current module,
   anything else (std, zenoh, koopman, ...) is another crate and ignored. The module segments are
   followed to a file (`a/b.rs` or `a/b/mod.rs`); the first non-module segment names an item of
   that file.
2. An item is attributed to the file that *defines* it: when the file the path reaches only
   imports the name (`pub use cluster::Cluster;` in orchestrator/mod.rs, or a private `use`),
   resolution follows that import, so `use super::Cluster` in run.rs is an edge to cluster.rs,
   not to mod.rs. A glob import (`use super::*`) is an edge to the module file it names.
3. An imported name makes an edge only if A's code mentions it outside `use` declarations: a
   `pub use child::X;` that only re-exports (the facade of a mod.rs) is not a use. Neither is
   `mod child;` — a parent declaring its children is not using them. So a child that uses items
   *defined* in its parent mod.rs and a mod.rs whose own code uses that child's items form a
   circle; a child using its parent beside a mod.rs that merely declares and re-exports it does
   not.
4. Inline modules (`mod tests { … }`) belong to their file; paths inside them count for the file
   (test code included: a test that reaches upward is a dependency too). Paths within one file
   are not edges. Intra-doc links (`[`super::x`]`) are comments and do not count.

A circle is a pair of different files A != B with A -> B and B -> A. Each is printed with one
place (file:line and the path written there) for each direction. Exit status 1 when any exists.

    python3 scripts/check-module-cycles.py [SRC_DIR ...]   # default: bridge/src koopman/src src

Each SRC_DIR is one crate: its root is lib.rs, or main.rs when there is no lib.rs. Its own test:
on the tree before issue 29 §4 it must find exactly the four bridge/ pairs that issue names.
"""

import pathlib
import re
import sys

IDENT = r"[A-Za-z_][A-Za-z0-9_]*"
KEYWORD_ROOTS = ("crate", "super", "self")


def strip_code(text: str) -> str:
    """`text` with comments, string and char literals blanked (newlines kept for line numbers)."""
    out = []
    i, n = 0, len(text)

    def blank(s: str) -> str:
        return "".join("\n" if c == "\n" else " " for c in s)

    while i < n:
        c = text[i]
        if text.startswith("//", i):
            j = text.find("\n", i)
            j = n if j < 0 else j
            out.append(blank(text[i:j]))
            i = j
        elif text.startswith("/*", i):
            depth, j = 1, i + 2
            while j < n and depth:
                if text.startswith("/*", j):
                    depth, j = depth + 1, j + 2
                elif text.startswith("*/", j):
                    depth, j = depth - 1, j + 2
                else:
                    j += 1
            out.append(blank(text[i:j]))
            i = j
        elif re.match(r'b?r#*"', text[i:i + 12]) and (i == 0 or not re.match(r"\w", text[i - 1])):
            m = re.match(r'(b?r)(#*)"', text[i:])
            hashes = m.group(2)
            end = text.find('"' + hashes, i + m.end())
            j = n if end < 0 else end + 1 + len(hashes)
            out.append('""' + blank(text[i + 2:j]))
            i = j
        elif c == '"':
            j = i + 1
            while j < n and text[j] != '"':
                j += 2 if text[j] == "\\" else 1
            j = min(j + 1, n)
            out.append('""' + blank(text[i + 2:j]))
            i = j
        elif c == "'":
            # A char literal ('x', '\n', '\u{1F600}', '\'') or a lifetime / label ('a, 'static).
            m = re.match(r"'(?:\\(?:u\{[0-9a-fA-F]+\}|x[0-9a-fA-F]{2}|.)|[^\\'\n])'", text[i:])
            if m:
                out.append(" " * m.end())
                i += m.end()
            else:
                out.append(c)
                i += 1
        else:
            out.append(c)
            i += 1
    return "".join(out)


def split_top(s: str) -> list:
    """`s` split at commas that are not inside braces."""
    parts, depth, cur = [], 0, []
    for c in s:
        if c == "{":
            depth += 1
        elif c == "}":
            depth -= 1
        if c == "," and depth == 0:
            parts.append("".join(cur))
            cur = []
        else:
            cur.append(c)
    parts.append("".join(cur))
    return [p.strip() for p in parts if p.strip()]


def expand_use(tree: str, prefix: list) -> list:
    """The leaves of a use tree as (path segments, local name or '*' for a glob)."""
    tree = tree.strip()
    if not tree:
        return []
    brace = tree.find("{")
    if brace >= 0 and tree.endswith("}"):
        head = tree[:brace].rstrip(":").strip()
        segs = prefix + [s for s in re.split(r"\s*::\s*", head) if s] if head else list(prefix)
        leaves = []
        for part in split_top(tree[brace + 1:-1]):
            leaves.extend(expand_use(part, segs))
        return leaves
    m = re.fullmatch(r"(.*?)\s+as\s+(" + IDENT + r")", tree, re.S)
    alias = None
    if m:
        tree, alias = m.group(1).strip(), m.group(2)
    segs = prefix + [s for s in re.split(r"\s*::\s*", tree) if s]
    if segs and segs[-1] == "*":
        return [(segs[:-1], "*")]
    if segs and segs[-1] == "self":
        segs = segs[:-1]
    if not segs:
        return []
    return [(segs, alias or segs[-1])]


class Crate:
    """The module files of one crate and what each file declares and uses."""

    def __init__(self, src: pathlib.Path):
        self.src = src
        root = src / "lib.rs"
        if not root.exists():
            root = src / "main.rs"
        self.root = root
        self.files = {}  # module path tuple -> file path
        self.modpath = {}  # file path -> module path tuple
        self._collect(root, ())
        self.parsed = {f: self._parse(f) for f in self.modpath}

    def _collect(self, path: pathlib.Path, mod: tuple) -> None:
        """Registers `path` as module `mod` and, recursively, the file modules it declares."""
        self.files[mod] = path
        self.modpath[path] = mod
        code = strip_code(path.read_text())
        if path.name in ("lib.rs", "main.rs", "mod.rs"):
            base = path.parent
        else:
            base = path.parent / path.stem
        for m in re.finditer(r"(?:#\[path\s*=[^\]]*\]\s*)?\bmod\s+(" + IDENT + r")\s*;", code):
            name = m.group(1)
            for cand in (base / f"{name}.rs", base / name / "mod.rs"):
                if cand.exists():
                    self._collect(cand, mod + (name,))
                    break

    def _parse(self, path: pathlib.Path) -> dict:
        """Inline modules, use declarations and inline paths of one file."""
        code = strip_code(path.read_text())
        mod = self.modpath[path]
        # Inline modules: (start, end, name) spans; the module a position is in is the path of
        # the spans around it.
        spans = []
        for m in re.finditer(r"\bmod\s+(" + IDENT + r")\s*\{", code):
            depth, j = 1, m.end()
            while j < len(code) and depth:
                depth += {"{": 1, "}": -1}.get(code[j], 0)
                j += 1
            spans.append((m.start(), j, m.group(1)))

        def scope(pos: int) -> tuple:
            return mod + tuple(name for s, e, name in spans if s < pos < e)

        def line(pos: int) -> int:
            return code.count("\n", 0, pos) + 1

        uses, use_ranges = [], []
        pattern = r"\b(?:pub(?:\s*\([^)]*\))?\s+)?use\s+([^;]*);"
        for m in re.finditer(pattern, code):
            use_ranges.append((m.start(), m.end()))
            for segs, name in expand_use(m.group(1), []):
                uses.append(
                    {"segs": segs, "name": name, "scope": scope(m.start()),
                     "line": line(m.start()), "top": scope(m.start()) == mod,
                     "text": " ".join(m.group(0).split())}
                )
        # `mod child;` declares, it does not use: blank it with the use declarations.
        for m in re.finditer(r"\bmod\s+" + IDENT + r"\s*;", code):
            use_ranges.append((m.start(), m.end()))
        outside = list(code)
        for s, e in use_ranges:
            outside[s:e] = " " * (e - s)
        body = "".join(outside)
        inline = []
        path_re = r"\b(?:crate|super|self)(?:\s*::\s*" + IDENT + r")+"
        for m in re.finditer(path_re, body):
            segs = re.split(r"\s*::\s*", m.group(0))
            inline.append({"segs": segs, "scope": scope(m.start()), "line": line(m.start()),
                           "text": m.group(0)})
        return {"uses": uses, "inline": inline, "body": body, "spans": spans}

    def absolute(self, segs: list, scope: tuple, in_use: bool):
        """`segs` as an absolute module path from the crate root, or None for another crate."""
        first = segs[0]
        if first == "crate":
            return list(segs[1:])
        if first in ("super", "self"):
            cur = list(scope)
            rest = list(segs)
            while rest and rest[0] in ("super", "self"):
                if rest[0] == "super":
                    cur = cur[:-1]
                rest = rest[1:]
            return cur + rest
        if in_use and tuple(scope) + (first,) in self.files:
            return list(scope) + list(segs)
        return None

    def resolve(self, abs_segs: list, depth: int = 0):
        """The file defining what `abs_segs` names: (file, is_glob_target)."""
        mod = ()
        i = 0
        while i < len(abs_segs) and mod + (abs_segs[i],) in self.files:
            mod = mod + (abs_segs[i],)
            i += 1
        path = self.files[mod]
        if i == len(abs_segs) or depth > 16:
            return path
        name = abs_segs[i]
        # Inline modules of the file and items defined there stay in this file; a name this
        # file only imports is followed to where it comes from.
        for use in self.parsed[path]["uses"]:
            if use["top"] and use["name"] == name:
                target = self.absolute(use["segs"], mod, True)
                if target is None:
                    return path
                return self.resolve(target + list(abs_segs[i + 1:]), depth + 1)
        return path

    def edges(self):
        """{(from_file, to_file): (line, text)} for every use of another file's items."""
        found = {}
        for path, info in self.parsed.items():
            body = info["body"]
            for use in info["uses"]:
                target = self.absolute(use["segs"], use["scope"], True)
                if target is None:
                    continue
                if use["name"] in ("*", "_"):  # a glob, or a trait imported for its methods
                    dest = self.files.get(tuple(target))
                    if dest is None:
                        dest = self.resolve(target)
                    where = use["text"]
                else:
                    hit = re.search(r"\b" + use["name"] + r"\b", body)
                    if hit is None:
                        continue  # a re-export only (`pub use child::X;`), not a use
                    dest = self.resolve(target)
                    where = f'{use["text"]} (used at line {body.count(chr(10), 0, hit.start()) + 1})'
                if dest != path:
                    found.setdefault((path, dest), (use["line"], where))
            for ref in info["inline"]:
                target = self.absolute(ref["segs"], ref["scope"], False)
                if target is None:
                    continue
                dest = self.resolve(target)
                if dest != path:
                    found.setdefault((path, dest), (ref["line"], ref["text"]))
        return found


def main(argv: list) -> int:
    repo = pathlib.Path(__file__).resolve().parent.parent
    if any(a in ("-h", "--help") for a in argv):
        print(__doc__)
        return 0
    dirs = [pathlib.Path(a) for a in argv] or [repo / d for d in ("bridge/src", "koopman/src", "src")]
    circles = 0
    for src in dirs:
        if not ((src / "lib.rs").exists() or (src / "main.rs").exists()):
            print(f"{src}: no lib.rs or main.rs", file=sys.stderr)
            return 2
        crate = Crate(src)
        edges = crate.edges()
        pairs = sorted({tuple(sorted((a, b))) for (a, b) in edges if (b, a) in edges})

        def rel(p: pathlib.Path) -> str:
            try:
                return str(p.resolve().relative_to(repo))
            except ValueError:
                return str(p)

        name = rel(src)
        print(f"{name}: {len(crate.files)} module files, {len(edges)} file-to-file uses, "
              f"{len(pairs)} two-file circle(s)")
        for a, b in pairs:
            la, ta = edges[(a, b)]
            lb, tb = edges[(b, a)]
            print(f"  {rel(a)} <-> {rel(b)}")
            print(f"      {rel(a)}:{la}: {ta}")
            print(f"      {rel(b)}:{lb}: {tb}")
        circles += len(pairs)
    return 1 if circles else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
