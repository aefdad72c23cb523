"""Atomic file output: every file the runtime writes appears whole or not at all, even across a power cut."""
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
    temporary file is removed and `path` is left as it was.

    The data is fsynced before the rename and the folder after it, so after a crash or power cut `path` holds
    the old content or the new, never an empty or partial file (a checkpoint hours in the making relies on
    this). It costs a few milliseconds per file; nothing writes files in a hot loop."""
    path = Path(path)
    tmp = temp_path(path)
    try:
        with open(tmp, "xb") as f:
            write(f)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)
    _fsync_folder(path.parent)
    return path


def _fsync_folder(folder: Path) -> None:
    """Make a rename in `folder` durable (POSIX; some file systems refuse fsync on a folder: the data is on disk)."""
    if os.name == "posix":
        fd = os.open(folder, os.O_RDONLY)
        try:
            os.fsync(fd)
        except OSError:
            pass
        finally:
            os.close(fd)
