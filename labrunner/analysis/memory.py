"""Freed memory back to the system while ``analyse`` builds and uses a table of 10^6 rows.

Two allocators keep what the process freed, as its memory, unless told otherwise:

- glibc's malloc serves a large allocation (≥ 128 kB) by ``mmap`` and unmaps it when freed —
  until a large block has been freed: it then raises that threshold to the block's size (up to
  32 MB), so that the table's columns, their temporaries and the many small pieces the table is
  built from come from the heap, where freed memory stays. Fixing the thresholds (as the
  environment variables ``MALLOC_MMAP_THRESHOLD_`` / ``MALLOC_TRIM_THRESHOLD_`` would; Dask's
  workers set the latter for the same reason) and trimming the heap after the big steps
  (:func:`trim`) returns it. Elsewhere (macOS, musl) this does nothing.
- pyarrow's default pool (mimalloc) keeps the segments of the text columns' many small
  temporaries; the system allocator (the glibc above) does not.

Measured on a synthetic 10^6-point ledger (benchmarks/synthetic_ledger.py, 2026-12-03): building
the table alone peaked at 555 MB with neither, 504 MB with both (ledger chunks of 5 000 rows; 488 MB
with the 2 000 now); the whole ``analyse``'s figures are in benchmarks/bench_scale.py.
"""

from __future__ import annotations

import ctypes
import platform

_M_TRIM_THRESHOLD = -1
_M_MMAP_THRESHOLD = -3
_THRESHOLD = 128 * 1024  # glibc's own initial value for both


def _glibc() -> ctypes.CDLL | None:
    if platform.libc_ver()[0] != "glibc":
        return None
    try:
        return ctypes.CDLL("libc.so.6")
    except OSError:
        return None


def return_freed_memory() -> None:
    """For the rest of this process: glibc's trim and mmap thresholds fixed at 128 kB, and
    pyarrow's allocations from the system allocator (see the module)."""
    libc = _glibc()
    if libc is not None:
        libc.mallopt(_M_TRIM_THRESHOLD, _THRESHOLD)
        libc.mallopt(_M_MMAP_THRESHOLD, _THRESHOLD)
    try:
        import pyarrow as pa
    except ImportError:
        return
    pa.set_memory_pool(pa.system_memory_pool())


def trim() -> None:
    """Give the free pages inside glibc's heap back to the system (``malloc_trim``)."""
    libc = _glibc()
    if libc is not None:
        libc.malloc_trim(0)
