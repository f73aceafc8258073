"""scripts/check-python-cycles.py finds two-file import circles in a package, follows a name an
``__init__`` only re-exports to the module that defines it, skips ``TYPE_CHECKING`` imports and
counts a lazy import inside a function; the koopbridge package itself has none."""

from __future__ import annotations

import subprocess
import sys
import textwrap
from pathlib import Path

from conftest import ROOT

SCRIPT = ROOT / "scripts" / "check-python-cycles.py"


def _package(tmp: Path, files: dict[str, str]) -> Path:
    root = tmp / "pkg"
    for name, text in files.items():
        p = root / name
        p.parent.mkdir(parents=True, exist_ok=True)
        p.write_text(textwrap.dedent(text))
    return root


def _run(*roots: Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, str(SCRIPT), *map(str, roots)], capture_output=True, text=True, timeout=60)


def test_circles_are_found_and_facades_are_not_circles(tmp_path):
    circle = _package(tmp_path / "c", {
        "__init__.py": "from .a import f\n",
        "a.py": "def f():\n    from . import b  # lazy: still an edge\n    return b\n",
        "b.py": "from pkg.a import f\n",
    })
    r = _run(circle)
    assert r.returncode == 1 and "1 two-file circle(s)" in r.stdout, r.stdout
    assert "a.py:2" in r.stdout and "b.py:1" in r.stdout, r.stdout

    clean = _package(tmp_path / "k", {
        "__init__.py": "from .a import f\nfrom .sub import g\n",
        "a.py": "from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from .b import h\ndef f():\n    return 1\n",
        "b.py": "from . import f  # the facade's name: defined in a.py\nfrom .a import f as f2\ndef h():\n    return f() + f2()\n",
        "sub/__init__.py": "from ..a import f\ndef g():\n    return f()\n",
    })
    r = _run(clean)
    assert r.returncode == 0 and "0 two-file circle(s)" in r.stdout, r.stdout


def test_the_koopbridge_package_has_no_circle():
    r = _run(ROOT / "adapters" / "python" / "python" / "koopbridge")
    assert r.returncode == 0, r.stdout
