"""Typed reads from JSON objects that name the file and the dotted field path when a value is wrong: how the
manifest (manifest.py) checks every field it reads."""
from __future__ import annotations

import math


class BundleError(ValueError):
    """A bundle that cannot be used: the message names the file and the field."""


class Fields:
    """Typed reads from one JSON object; every failure names the file and the dotted field path."""

    def __init__(self, obj, where: str, path: str = "", error: type[ValueError] = BundleError):
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
