#!/usr/bin/env python3
"""Checks that the move of BENCHMARKS.md into a topic reference + docs/log/ lost no figure.

Plain python3, no dependencies. Takes the BENCHMARKS.md of a git revision (default 6aa4292, the
last one ordered by session) and checks, against the working tree:

1. every numeric token of the old file (with the line it stood on as context) occurs in the new
   BENCHMARKS.md or in docs/log/*.md — as a whole token, not as part of a longer number;
2. for every numeric token, docs/log/ holds at least as many occurrences as the old file (the log
   is a verbatim copy, so a count below the old one means a figure was dropped or altered);
3. every non-blank line of the old file, except its title, occurs verbatim in docs/log/ (so each
   figure still stands beside its command, machine and load);
4. unless --no-notes (and when docs/decisions/ exists): every non-blank line of notes/*.md and
   notes/unlanded/*.md of the same revision, notes/README.md excepted (replaced by a pointer to
   docs/), occurs verbatim in docs/decisions/*.md (headings may have moved down a level).

It also lists, for review, the numeric tokens of the new BENCHMARKS.md that occur neither in the
old file nor in docs/decisions/ (a typo in a copied figure shows up there; dates and decision
numbers are expected). Exit status 1 when check 1, 2, 3 or 4 fails.

    python3 scripts/check-figures.py [--rev 6aa4292] [--no-notes] [--verbose]
"""

import argparse
import collections
import pathlib
import re
import subprocess
import sys

# A number as figures are written here: 0.008741, 1,957, 180,000, 6.4e8, 1.4545e-6, 2.84, 17382.
# Leading sign and trailing units/× are not part of the token.
NUMBER = re.compile(r"(?<![\w.])\d+(?:,\d{3})*(?:\.\d+)?(?:[eE][+-]?\d+)?(?![\w])")


def git_show(rev: str, path: str) -> str:
    """The text of `path` at `rev` (raises if git cannot show it)."""
    return subprocess.run(
        ["git", "show", f"{rev}:{path}"], check=True, capture_output=True, text=True
    ).stdout


def git_ls(rev: str, prefix: str) -> list[str]:
    """Paths under `prefix` at `rev` ending in .md."""
    out = subprocess.run(
        ["git", "ls-tree", "-r", "--name-only", rev, prefix],
        check=True,
        capture_output=True,
        text=True,
    ).stdout
    return [p for p in out.splitlines() if p.endswith(".md")]


def tokens(text: str) -> collections.Counter:
    """Multiset of the numeric tokens of `text`."""
    return collections.Counter(m.group(0) for m in NUMBER.finditer(text))


def heading_free(line: str) -> str:
    """`line` without trailing blanks and without a leading Markdown heading marker."""
    return re.sub(r"^#+\s+", "", line.rstrip())


def read_all(paths) -> str:
    """The concatenated text of `paths`."""
    return "\n".join(p.read_text(encoding="utf-8") for p in paths)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--rev", default="6aa4292", help="revision of the old BENCHMARKS.md and notes/")
    ap.add_argument("--root", default=".", help="repository root (default: the current folder)")
    ap.add_argument("--no-notes", action="store_true", help="skip check 4 (notes -> docs/decisions)")
    ap.add_argument("--verbose", action="store_true", help="print every missing item, not the first 40")
    args = ap.parse_args()

    root = pathlib.Path(args.root)
    old = git_show(args.rev, "BENCHMARKS.md")
    new_ref = (root / "BENCHMARKS.md").read_text(encoding="utf-8")
    log_paths = sorted((root / "docs/log").glob("*.md"))
    if not log_paths:
        print("docs/log/*.md: none found")
        return 1
    log = read_all(log_paths)
    new_tokens = tokens(new_ref) + tokens(log)
    log_tokens = tokens(log)
    old_tokens = tokens(old)
    limit = None if args.verbose else 40
    failed = False

    # 1. every numeric token, with its line as context
    missing = []
    for n, line in enumerate(old.splitlines(), 1):
        for m in NUMBER.finditer(line):
            if new_tokens[m.group(0)] == 0:
                missing.append((n, m.group(0), line.strip()))
    n_occ = sum(old_tokens.values())
    print(f"1. numeric tokens of BENCHMARKS.md@{args.rev}: {n_occ} occurrences, "
          f"{len(old_tokens)} distinct; missing from BENCHMARKS.md + docs/log/: {len(missing)}")
    for n, tok, line in missing[:limit]:
        print(f"   line {n}: {tok!r} in: {line[:140]}")
    failed |= bool(missing)

    # 2. counts: the log holds every occurrence
    short = {t: (c, log_tokens[t]) for t, c in old_tokens.items() if log_tokens[t] < c}
    print(f"2. tokens with fewer occurrences in docs/log/ than in the old file: {len(short)}")
    for t, (c, k) in list(short.items())[:limit]:
        print(f"   {t!r}: old {c}, log {k}")
    failed |= bool(short)

    # 3. every line verbatim in the log (the title line excepted)
    log_lines = set(line.rstrip() for line in log.splitlines())
    old_lines = [line.rstrip() for line in old.splitlines()]
    absent = [
        (n, line) for n, line in enumerate(old_lines, 1)
        if line.strip() and n > 1 and line not in log_lines
    ]
    print(f"3. non-blank lines of the old file (title excepted): "
          f"{sum(1 for line in old_lines[1:] if line.strip())}; not verbatim in docs/log/: {len(absent)}")
    for n, line in absent[:limit]:
        print(f"   line {n}: {line[:140]}")
    failed |= bool(absent)

    # 4. notes -> docs/decisions
    decisions_dir = root / "docs/decisions"
    decisions = read_all(sorted(decisions_dir.glob("*.md"))) if decisions_dir.is_dir() else ""
    if not args.no_notes and decisions_dir.is_dir():
        dec_lines = set(heading_free(line) for line in decisions.splitlines())
        notes = [p for p in git_ls(args.rev, "notes") if p != "notes/README.md"]
        lost = []
        total = 0
        for path in notes:
            for n, line in enumerate(git_show(args.rev, path).splitlines(), 1):
                if line.strip():
                    total += 1
                    if heading_free(line) not in dec_lines:
                        lost.append((path, n, line))
        print(f"4. non-blank lines of {len(notes)} notes files@{args.rev}: {total}; "
              f"not verbatim in docs/decisions/: {len(lost)}")
        for path, n, line in lost[:limit]:
            print(f"   {path}:{n}: {line[:140]}")
        failed |= bool(lost)

    # For review: numbers of the reference found neither in the old file nor in the decisions.
    known = old_tokens + tokens(decisions)
    novel = sorted(t for t in tokens(new_ref) if known[t] == 0)
    print(f"review: numeric tokens of the new BENCHMARKS.md found neither in the old file nor in "
          f"docs/decisions/: {len(novel)}" + (f": {', '.join(novel)}" if novel else ""))
    in_ref = sum(1 for t in old_tokens if tokens(new_ref)[t] > 0)
    print(f"info: distinct tokens of the old file also in the topic reference: {in_ref} of "
          f"{len(old_tokens)} (the rest are in docs/log/ only)")
    print("FAILED" if failed else "OK: no figure lost in the move")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
