"""Atomic file output: every file the runtime writes appears whole or not at all, even across a power cut, and a
process killed at any moment leaves no half-written file and no stray temporary file in the user's folder.

What holds, for `write_atomic(path, ...)` and `staged_output(path)` (every writer of the runtime and of training
goes through them):

1. `path` holds its old content or the new, never a partial file, also after a kill -9 or a power cut: the data
   is fsynced before it gets the name `path`, and the folder after.
2. No stray files (POSIX). On Linux (file systems with O_TMPFILE: ext4, xfs, btrfs, tmpfs, ...) the data is
   written to an *anonymous* file in the target's folder: it has no name, so a process killed while writing it
   leaves nothing behind (the kernel frees it). When it is complete it is linked in (`linkat` through
   /proc/self/fd): a new file gets its name in one step, with no temporary name at all; replacing an existing
   file needs a temporary name for the microseconds between that link and the rename over `path`. Where
   O_TMPFILE is missing (macOS, other file systems) the data goes to a named temporary file beside `path`.
   Every temporary name carries the writing process's id and a tag of its host and pid namespace
   (`.NAME.PID-TAG-RANDOM.mogo-tmp.EXT`), and the first write of a process into a folder removes the ones
   whose process is gone (`sweep_stale`). So after a kill -9, whatever a write was doing, the folder holds no
   stray file (Linux, new file), or at most one that the next write into that folder removes. A reused pid
   only delays that; a live process's file is never removed. On Windows (no cheap liveness check) stale
   temporary files are left to the user.
3. An OSError while writing (disk full, quota, I/O error, a folder in the way) is raised as OutputError, whose
   message starts with `path`, and the temporary data is discarded.

A writer that cannot hand over a file object (ffmpeg) gets `Staged.external_name`, a path a child process can
open to write the same file (with `Staged.pass_fds` passed to it), so it is covered by the same guarantees.
"""
from __future__ import annotations

import errno
import hashlib
import os
import re
import secrets
import shutil
import socket
import threading
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import BinaryIO, Callable, Iterator


class OutputError(OSError):
    """A file cannot be written where it was asked to go (missing permission, a parent that is a file, a full
    disk...). The message starts with the file's path; `errno` is the underlying error's, when there was one."""


_SUFFIX = ".mogo-tmp"
# .NAME.PID-TAG-RANDOM.mogo-tmp[.EXT]
_TEMP = re.compile(r"^\.(?P<name>.+)\.(?P<pid>\d+)-(?P<tag>[0-9a-f]{8})-[0-9a-f]{8}\.mogo-tmp(?P<ext>\.[^.]*)?$")
# what earlier versions named their temporaries: .NAME.PID.RANDOM.tmpEXT, EXT being NAME's own suffix
_LEGACY = re.compile(r"^\.(?P<name>.+)\.(?P<pid>\d+)\.[0-9a-f]{8}\.tmp(?P<ext>\.[^.]*)?$")
_NAME_KEEP = 120        # characters of the target's name kept in a temporary name: NAME_MAX is 255
_swept: set[str] = set()
_lock = threading.Lock()
_anonymous_ok = hasattr(os, "O_TMPFILE")   # cleared for the process the first time linking one in fails


def _host_tag() -> str:
    """Tells this host and pid namespace apart from others sharing the folder (NFS, containers): a pid is only
    checked for life where it means the same process."""
    try:
        ns = os.readlink("/proc/self/ns/pid")
    except OSError:
        ns = ""
    return hashlib.sha1(f"{socket.gethostname()}\0{ns}".encode()).hexdigest()[:8]


_TAG = _host_tag()


def _temp_name(path: Path) -> str:
    return f".{path.name[:_NAME_KEEP]}.{os.getpid()}-{_TAG}-{secrets.token_hex(4)}{_SUFFIX}{path.suffix}"


@dataclass
class Staged:
    """The file being written, before it has its name."""
    file: BinaryIO          # open for reading and writing, at offset 0
    external_name: str      # a path another process (given pass_fds) can open to write this same file
    pass_fds: tuple[int, ...]


@contextmanager
def staged_output(path: str | Path) -> Iterator[Staged]:
    """Write `path` through `Staged.file` (or `Staged.external_name`); on leaving the block without an exception
    the file gets its name (see the module docstring for what holds), else it is discarded and `path` stays as
    it was. OSErrors, here or in the block, are raised as OutputError naming `path`."""
    path = Path(path)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        sweep_stale(path.parent)
        folder = _Folder(path.parent)
    except OSError as e:
        raise _output_error(path, e) from None
    try:
        anonymous = _open_anonymous(folder)
        if anonymous is not None:
            yield from _staged_anonymous(path, folder, anonymous)
        else:
            yield from _staged_named(path, folder)
    except OSError as e:
        raise _output_error(path, e) from None
    finally:
        folder.close()


def write_atomic(path: str | Path, write: Callable[[BinaryIO], object]) -> Path:
    """Call `write(f)` on a file that becomes `path` only once it is complete and on disk (the module
    docstring says what holds); on any failure `path` is left as it was. Raises OutputError naming `path` for an
    OSError. It costs a few milliseconds per file (fsync); nothing writes files in a hot loop."""
    path = Path(path)
    with staged_output(path) as out:
        write(out.file)
    return path


def sweep_stale(folder: str | Path) -> list[Path]:
    """Remove the temporary files in `folder` left by processes that are gone (kill -9, power cut); once per
    folder and process, on its first write there. Returns what was removed."""
    key = os.path.abspath(folder)
    with _lock:
        if key in _swept:
            return []
        _swept.add(key)
    removed = []
    for p in stale_temps(folder):
        try:
            p.unlink()
            removed.append(p)
        except FileNotFoundError:
            pass                       # another process swept it first
        except OSError:
            pass                       # not ours to insist on: a read-only or foreign folder keeps it
    return removed


def stale_temps(folder: str | Path) -> list[Path]:
    """The temporary files in `folder` whose writer is gone, on this host and pid namespace (POSIX only)."""
    if os.name != "posix":
        return []
    try:
        names = os.listdir(folder)
    except OSError:
        return []
    out = []
    for name in names:
        m = _TEMP.match(name)
        if m is not None and m["tag"] != _TAG:
            continue                   # another host's or container's pid: cannot tell whether it lives
        if m is None:
            m = _LEGACY.match(name)
            if m is None or (m["ext"] or "") != Path(m["name"]).suffix:
                continue
        pid = int(m["pid"])
        if pid > 0 and not process_alive(pid):
            out.append(Path(folder) / name)
    return sorted(out)


def process_alive(pid: int) -> bool:
    """Whether process `pid` (of this pid namespace) may still write: alive and not a zombie."""
    if pid == os.getpid():
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except OSError:
        return True                    # exists, someone else's
    try:                               # killed but not yet reaped by its parent: it will never write again
        with open(f"/proc/{pid}/stat", "rb") as f:
            return f.read().rsplit(b")", 1)[1].split()[0] not in (b"Z", b"X")
    except (OSError, IndexError):
        return True


def _output_error(path: Path, e: OSError) -> OutputError:
    if isinstance(e, OutputError):
        return e
    err = OutputError(f"{path}: cannot write it ({e.strerror or e})")
    err.errno = e.errno
    return err


def _fdopen(fd: int) -> BinaryIO:
    """The file object writers get, owning `fd` (closed here if that fails); a seam for tests that simulate a full
    disk."""
    try:
        return os.fdopen(fd, "w+b")
    except BaseException:
        os.close(fd)
        raise


def _open_anonymous(folder: "_Folder") -> int | None:
    """An unnamed file in `folder` (O_TMPFILE), or None where the OS or the file system has none."""
    if not _anonymous_ok or folder.fd is None:
        return None
    try:
        return os.open(".", os.O_TMPFILE | os.O_RDWR, 0o666, dir_fd=folder.fd)   # umask applies, as for any file
    except OSError as e:
        # unsupported: EOPNOTSUPP (the file system), EISDIR or EINVAL (a kernel without O_TMPFILE)
        if e.errno in (errno.EOPNOTSUPP, errno.ENOTSUP, errno.EISDIR, errno.EINVAL):
            return None
        raise


# errors of linking through /proc/self/fd that mean "not here" (no /proc, a sandbox that refuses it), not a
# problem with the output: the data is then copied to a named temporary file instead
_NO_PROC_LINK = (errno.ENOENT, errno.EXDEV, errno.EPERM, errno.ENOSYS, errno.EOPNOTSUPP, errno.EINVAL)


def _staged_anonymous(path: Path, folder: "_Folder", fd: int):
    global _anonymous_ok
    with _fdopen(fd) as f:
        source = f"/proc/self/fd/{fd}"
        yield Staged(f, source, (fd,))
        f.flush()
        os.fsync(fd)
        try:
            folder.link(source, path.name)         # a new file: named in one step, no temporary name ever exists
        except FileExistsError:
            tmp = _temp_name(path)
            folder.link(source, tmp)
            folder.replace(tmp, path.name)
        except OSError as e:
            if e.errno not in _NO_PROC_LINK:
                raise
            _anonymous_ok = False
            _copy_to_named(f, path, folder)
    folder.fsync()


def _staged_named(path: Path, folder: "_Folder"):
    tmp = _temp_name(path)
    fd = folder.create(tmp)
    try:
        with _fdopen(fd) as f:
            yield Staged(f, str(path.parent / tmp), ())
            f.flush()
            os.fsync(f.fileno())
        folder.replace(tmp, path.name)
    except BaseException:
        folder.unlink(tmp)
        raise
    folder.fsync()


def _copy_to_named(src: BinaryIO, path: Path, folder: "_Folder") -> None:
    src.seek(0)
    with contextmanager(_staged_named)(path, folder) as staged:
        shutil.copyfileobj(src, staged.file, 1 << 20)


# os.replace takes dir fds as os.rename does, though supports_dir_fd lists only os.rename
_DIR_FD = os.name == "posix" and {os.open, os.link, os.rename, os.unlink} <= os.supports_dir_fd


class _Folder:
    """The output's folder, held open where the OS allows (so every step acts on the same folder, and its
    entry can be fsynced), else by path."""

    def __init__(self, path: Path):
        self.path = path
        self.fd = os.open(path, os.O_RDONLY | getattr(os, "O_DIRECTORY", 0)) if _DIR_FD else None

    def create(self, name: str) -> int:
        flags = os.O_RDWR | os.O_CREAT | os.O_EXCL | getattr(os, "O_BINARY", 0)
        if self.fd is None:
            return os.open(self.path / name, flags, 0o666)
        return os.open(name, flags, 0o666, dir_fd=self.fd)

    def link(self, source: str, name: str) -> None:
        # dst_dir_fd makes os.link call linkat(AT_SYMLINK_FOLLOW): plain link() would link the /proc symlink
        os.link(source, name, dst_dir_fd=self.fd, follow_symlinks=True)

    def replace(self, tmp: str, name: str) -> None:
        try:
            if self.fd is None:
                os.replace(self.path / tmp, self.path / name)
            else:
                os.replace(tmp, name, src_dir_fd=self.fd, dst_dir_fd=self.fd)
        except BaseException:
            self.unlink(tmp)
            raise

    def unlink(self, name: str) -> None:
        try:
            if self.fd is None:
                os.unlink(self.path / name)
            else:
                os.unlink(name, dir_fd=self.fd)
        except OSError:
            pass

    def fsync(self) -> None:
        """Make the new name durable (some file systems refuse fsync on a folder: the data is on disk)."""
        if self.fd is not None:
            try:
                os.fsync(self.fd)
            except OSError:
                pass

    def close(self) -> None:
        if self.fd is not None:
            os.close(self.fd)
