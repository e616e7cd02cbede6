"""A benchmark's ``--threads``, read before numba is imported (numba fixes its pool then)."""

from __future__ import annotations

import os


def numba_threads_from_argv(argv, default: int = 2) -> int:
    """``--threads N`` (or ``--threads=N``) of ``argv``, else ``default``, put into
    NUMBA_NUM_THREADS for numba to read when it is first imported; returns it."""
    threads = default
    for i, a in enumerate(argv):
        if a == "--threads" and i + 1 < len(argv):
            threads = int(argv[i + 1])
        elif a.startswith("--threads="):
            threads = int(a.split("=", 1)[1])
    os.environ["NUMBA_NUM_THREADS"] = str(threads)
    return threads
