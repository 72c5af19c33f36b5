"""Run one piece of the analysis in a forked child while the process goes on with the rest.

``analyse`` draws the run plots (reading their logs, ~0.2 s a plot) in a child forked after
matplotlib, pandas and the campaign are loaded, so the child pays no imports and starts at once,
while the parent draws the maps and writes the tables; on two cores that takes the run plots off
the analysis's wall time. The result comes back pickled through a pipe. Where there is no
``fork`` (Windows) or when the child fails, the function simply runs in this process when its
result is asked for: the same result, only later.
"""

from __future__ import annotations

import gc
import os
import pickle
import sys
import warnings
from collections.abc import Callable
from typing import Generic, TypeVar

T = TypeVar("T")


class Background(Generic[T]):
    """``fn()`` in a forked child (if ``fork``); :meth:`result` waits for it and returns its value."""

    def __init__(self, fn: Callable[[], T]) -> None:
        self._fn = fn
        self._pid = 0
        self._read = -1
        if hasattr(os, "fork"):
            self._start()

    def _start(self) -> None:
        read, write = os.pipe()
        for stream in (sys.stdout, sys.stderr):  # nothing buffered twice
            stream.flush()
        gc.freeze()  # neither process's collector walks (and so copies) the objects they share
        with warnings.catch_warnings():  # 3.12+ warns on fork with threads; the child only draws and writes files
            warnings.simplefilter("ignore", DeprecationWarning)
            pid = os.fork()
        if pid == 0:  # the child: never returns into the caller's code
            code = 1
            try:
                gc.disable()
                os.close(read)
                with os.fdopen(write, "wb") as pipe:
                    pickle.dump(self._fn(), pipe)
                code = 0
            finally:
                os._exit(code)
        os.close(write)
        self._pid, self._read = pid, read

    def result(self) -> T:
        """The child's result; if there is no child or it failed, ``fn()`` run here."""
        if not self._pid:
            return self._fn()
        with os.fdopen(self._read, "rb") as pipe:
            data = pipe.read()
        _, status = os.waitpid(self._pid, 0)
        self._pid = 0
        gc.unfreeze()
        if status == 0 and data:
            return pickle.loads(data)
        return self._fn()

    def close(self) -> None:
        """Wait for a child whose result is no longer wanted (the analysis failed before it)."""
        if self._pid:
            os.close(self._read)
            os.waitpid(self._pid, 0)
            self._pid = 0
            gc.unfreeze()
