"""Atomic file output: every file the runtime writes appears whole or not at all."""
from __future__ import annotations

import os
import secrets
from pathlib import Path
from typing import BinaryIO, Callable


def temp_path(path: Path) -> Path:
    """A fresh name beside `path` (same folder, so os.replace is atomic), keeping its suffix for tools that
    pick a format by extension. Not created here: whoever creates it gets the usual umask permissions
    (mkstemp would leave the final file 0600)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    return path.with_name(f".{path.name}.{os.getpid()}.{secrets.token_hex(4)}.tmp{path.suffix}")


def write_atomic(path: Path, write: Callable[[BinaryIO], object]) -> Path:
    """Call `write(f)` on a temporary file beside `path`, then rename it into place; on any failure the
    temporary file is removed and `path` is left as it was."""
    tmp = temp_path(path)
    try:
        with open(tmp, "xb") as f:
            write(f)
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)
    return path
