"""Where the ``koopbridge`` command-line program is, for the Python code that starts it."""

from __future__ import annotations

import os
import shutil
from pathlib import Path

__all__ = ["find_cli", "koopbridge_cli"]


def find_cli() -> Path | None:
    """The ``koopbridge`` CLI: ``$KOOPBRIDGE_BIN``, ``$CARGO_TARGET_DIR/release``, the
    repository's ``target/release`` (this package's checkout), then ``PATH``; ``None`` if none
    is an executable file."""
    root = Path(__file__).resolve().parents[4]
    cands = [os.environ.get("KOOPBRIDGE_BIN")]
    if os.environ.get("CARGO_TARGET_DIR"):
        cands.append(os.path.join(os.environ["CARGO_TARGET_DIR"], "release", "koopbridge"))
    cands += [str(root / "target" / "release" / "koopbridge"), shutil.which("koopbridge")]
    for c in cands:
        if c and os.path.isfile(c) and os.access(c, os.X_OK):
            return Path(c)
    return None


def koopbridge_cli() -> str:
    """``find_cli()`` as a string; ``FileNotFoundError`` naming what to do when it is not built."""
    found = find_cli()
    if found is None:
        raise FileNotFoundError("the koopbridge CLI was not found (cargo build --release, or set KOOPBRIDGE_BIN)")
    return str(found)
