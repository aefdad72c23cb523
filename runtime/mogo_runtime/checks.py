"""Checks of values that come from outside (a user's arguments, a bundle's manifest, a rig file): numbers that must
be real and in range, files that must be regular and small, and typed reads from JSON objects that name the file and
the dotted field when a value is wrong. Every error is a ValueError (or the subclass a caller names) with one line
saying what is wrong."""
from __future__ import annotations

import errno
import math
import numbers
import os
import stat

import numpy as np

NAME_MAX = 255      # bytes of one file name on the file systems a bundle or a motion file lands on (ext4, APFS, NTFS)


def read_file(path, most: int, links: bool = True, error: type[ValueError] = ValueError) -> bytes:
    """The bytes of `path`, a regular file of at most `most` bytes. A device (/dev/zero), a FIFO (which would block)
    or a folder is refused before a byte is read, and so is a link where `links` is False (a link could point at
    any file of the machine); never more than `most` + 1 bytes are read, whatever the file's size says."""
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | (0 if links else getattr(os, "O_NOFOLLOW", 0)))
    except OSError as e:
        why = "a link, which is not allowed here" if e.errno == errno.ELOOP else f"cannot read it ({e.strerror})"
        raise error(f"{path}: {why}") from None
    with os.fdopen(fd, "rb") as f:
        mode = os.fstat(fd).st_mode
        if not stat.S_ISREG(mode):
            raise error(f"{path}: not a regular file ({'a folder' if stat.S_ISDIR(mode) else 'a device or pipe'})")
        data = f.read(most + 1)
    if len(data) > most:
        raise error(f"{path}: more than {most:,} bytes")
    return data


def shown(value, limit: int = 60) -> str:
    """repr for an error message: cut short, and safe for an int too long for str() (which raises ValueError)."""
    try:
        text = repr(value)
    except ValueError:
        return f"an int of {value.bit_length()} bits"
    return text if len(text) <= limit else text[:limit] + "..."


def as_real(name: str, value, must: str, lo: float = -math.inf, hi: float = math.inf) -> float:
    """`value` as a float in [lo, hi], else ValueError "{name} must be [a number] {must}, got ...".

    Any real scalar is a number here (Python, numpy, Fraction); a bool is not (True would run as 1), nor a
    string, nor an int too large for a float (float() raises OverflowError on it). NaN and infinity are numbers
    outside every range."""
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, numbers.Real):
        raise ValueError(f"{name} must be a number {must}, got {shown(value)}")
    try:
        x = float(value)
    except OverflowError:
        x = math.inf
    if not (math.isfinite(x) and lo <= x <= hi):
        raise ValueError(f"{name} must be {must}, got {shown(value)}")
    return x


def check_fps(fps) -> float:
    """Frames per second: a real number > 0."""
    return as_real("fps", fps, "> 0 (frames per second)", math.ulp(0.0))


def as_int(name: str, value, must: str, lo: int, hi: int | None = None) -> int:
    """`value` as an int in [lo, hi] (any integral scalar, numpy's included, never a bool), else ValueError."""
    if (isinstance(value, (bool, np.bool_)) or not isinstance(value, numbers.Integral)
            or not lo <= value <= (math.inf if hi is None else hi)):
        raise ValueError(f"{name} must be {must}, got {shown(value)}")
    return int(value)


class Fields:
    """Typed reads from one JSON object; every failure raises `error` naming the file and the dotted field path."""

    def __init__(self, obj, where: str, path: str = "", error: type[ValueError] = ValueError):
        self.where, self.path, self.error = where, path, error
        if not isinstance(obj, dict):
            name = f": field {path}" if path else ""
            raise error(f"{where}{name}: must be a JSON object, got {kind(obj)}")
        self.obj = obj

    def _name(self, key) -> str:
        return ".".join(p for p in (self.path, key) if p)

    def fail(self, key, message: str):
        raise self.error(f"{self.where}: field {self._name(key)}: {message}")

    def get(self, key, default=...):
        if key not in self.obj:
            if default is ...:
                self.fail(key, "missing")
            return default
        return self.obj[key]

    def int(self, key, lo: int = 0, hi: int = 2 ** 31, default=...) -> int:
        v = self.get(key, default)
        if isinstance(v, bool) or not isinstance(v, int) or not lo <= v <= hi:
            self.fail(key, f"expected an integer in [{lo}, {hi}], got {v!r}")
        return v

    def num(self, key, lo: float, hi: float, default=...) -> float:
        v = self.get(key, default)
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or not lo < v <= hi:
            self.fail(key, f"expected a number in ({lo:g}, {hi:g}], got {v!r}")
        return float(v)

    def str(self, key, default=...) -> str:
        v = self.get(key, default)
        if not isinstance(v, str) or not v:
            self.fail(key, f"expected a non-empty string, got {v!r}")
        return v

    def sub(self, key, default=...) -> "Fields":
        return Fields(self.get(key, default), self.where, self._name(key), self.error)

    def list(self, key) -> list:
        v = self.get(key)
        if not isinstance(v, list):
            self.fail(key, f"expected a list, got {kind(v)}")
        return v


def kind(v) -> str:
    return "null" if v is None else type(v).__name__
