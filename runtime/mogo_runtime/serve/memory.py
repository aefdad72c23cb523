"""The motion server's memory: handing what malloc holds free back to the system, and the process's resident size
for the status line."""
from __future__ import annotations

import functools

# How often the tick thread hands the memory malloc holds free back to the system. glibc keeps freed blocks in its
# heap: a restored server's characters rebuild their contexts together, and their passing peak stayed resident (800
# characters of the tests' tiny model: 322 MB against 226 for the same crowd started staggered; 207 and 206 after
# a trim). A trim took 2.6 ms there, 11 ms beside 256 base characters.
TRIM_SECONDS = 30.0


def return_free_memory() -> None:
    """glibc's malloc_trim(0); nothing elsewhere (other C libraries manage their heaps their own way)."""
    trim = malloc_trim()
    if trim is not None:
        trim(0)


@functools.cache
def malloc_trim():
    try:
        import ctypes

        return ctypes.CDLL("libc.so.6").malloc_trim
    except (OSError, AttributeError):
        return None


def rss_mb() -> float:
    try:
        with open("/proc/self/status") as f:
            return next(int(line.split()[1]) for line in f if line.startswith("VmRSS:")) / 1024
    except (OSError, StopIteration, ValueError):
        return float("nan")
