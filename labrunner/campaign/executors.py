"""Where a campaign's batches run, and how the scheduler supervises and abandons them.

Every executor is a :class:`concurrent.futures.Executor` wrapped in an :class:`ExecutorHandle`
that adds the two things supervision needs beyond ``submit``:

- ``probe()`` — "" while the executor is healthy, else why not (a Dask worker or the scheduler
  lost; a process pool reports a dead worker itself, as ``BrokenProcessPool`` on every future);
  ``orphaned()`` — True once no running batch can ever return (the Dask scheduler is gone), so the
  scheduler abandons them at once instead of waiting out its deadline for them;
- ``abandon()`` — give up on running batches at once: pool workers are killed with SIGKILL (they
  ignore SIGINT/SIGTERM, so ``ProcessPoolExecutor``'s own clean-up, which sends SIGTERM and then
  joins them, would wait forever), Dask futures are cancelled on the cluster;
- ``stop(level)`` — workers leave queued batches unrun, and with ``STOP_RUNNING`` stop running
  ones too (:mod:`labrunner.campaign.live`: a pool's shared word, sent to a Dask cluster's
  workers); None in-process. ``cancel_queued``: whether queued futures may be cancelled too
  (Dask, in-process; never a pool's).

Executors:

- a local process pool (default; ``--workers N``, default all cores), workers forked as soon as
  the pool opens (they import what a batch needs while the runner validates the campaign), ignoring
  SIGINT/SIGTERM (the parent decides what Ctrl-C means) and killed if the parent dies
  (``PR_SET_PDEATHSIG``), reporting their batches' ticks, and their representative runs' signals for the
  live view, through shared arrays (:mod:`labrunner.campaign.live`);
- a Dask distributed cluster (``--executor tcp://HOST:PORT``: ``Client(address).get_executor()``);
  its workers must see the campaign directory (shared file system) and report their batches'
  ticks as Dask events on a topic the client subscribes to;
- in-process, one run at a time, for a real rig.

At most :data:`QUEUE_DEPTH` batches per slot are in flight (one running, the next queued behind it).
"""

from __future__ import annotations

import contextlib
import ctypes
import importlib
import multiprocessing
import os
import pickle
import signal
import socket
import time
import uuid
from collections.abc import Callable, Iterator
from concurrent.futures import Executor, Future, ProcessPoolExecutor
from dataclasses import dataclass, field
from typing import Any
from urllib.parse import urlsplit

from labrunner.campaign import live
from labrunner.errors import CampaignError, InvalidParameter

STOP_SIGNALS = {signal.SIGINT, signal.SIGTERM}
DASK_PORT = 8786  # the Dask scheduler's default port
#: How long idle pool workers get to exit when a session ends; one still there then (stopped with
#: SIGSTOP, hung) is killed, so that a stopped worker never hangs the runner.
SHUTDOWN_S = 10.0
CONNECT_TIMEOUT_S = 5.0  # reaching a Dask scheduler before anything is created
_PR_SET_PDEATHSIG = 1
QUEUE_DEPTH = 2  # batches in flight per slot
#: Imported by each pool worker as it starts, in parallel with the parent's validation of the
#: campaign: the engine and the log writer. No twin needs scipy (the motor's matrix exponential is
#: labrunner.rigs.sim._integrate.expm) and neither does an N = 0 differentiator
#: (labrunner.differentiators.kernel); an N > 0 one imports scipy.special in its first batch.
WORKER_MODULES = ("labrunner.engine", "labrunner.logs.writer")


class InProcessExecutor(Executor):
    """Runs each call in the caller's process at submit time: a real rig, one run at a time."""

    def submit(self, fn: Callable[..., Any], /, *args: Any, **kwargs: Any) -> Future:
        future: Future = Future()
        future.set_running_or_notify_cancel()
        try:
            future.set_result(fn(*args, **kwargs))
        except Exception as exc:
            future.set_exception(exc)
        return future


class PackedExecutor(Executor):
    """Submits each call to ``executor`` as one pickled blob, unpacked by the worker that runs it.

    A Dask scheduler unpickles every task it is sent: a batch of ~1000 points became ~10^4 small
    Python objects in the scheduler, freed only by its cyclic collector, and the scheduler's
    memory grew with every run (~2.5 kB a run: 1.9 GB after the 751 028 runs of one session of a
    10^6-point campaign).
    As one ``bytes`` object, a batch costs the scheduler one allocation, returned when the task
    is forgotten."""

    def __init__(self, executor: Executor) -> None:
        self.executor = executor

    def submit(self, fn: Callable[..., Any], /, *args: Any, **kwargs: Any) -> Future:
        import cloudpickle  # as Dask pickles a task: a function by reference where it can be imported

        return self.executor.submit(_unpacked, cloudpickle.dumps((fn, args, kwargs), protocol=pickle.HIGHEST_PROTOCOL))

    def shutdown(self, wait: bool = True, *, cancel_futures: bool = False) -> None:
        self.executor.shutdown(wait=wait, cancel_futures=cancel_futures)


def _unpacked(blob: bytes) -> Any:
    """Run a call :class:`PackedExecutor` packed (in the worker)."""
    fn, args, kwargs = pickle.loads(blob)
    return fn(*args, **kwargs)


@dataclass
class ExecutorHandle:
    """An executor, its number of parallel slots, its supervision hooks (see module docstring),
    and its live channel (None: none, a real rig's one run at a time)."""

    executor: Executor
    slots: int
    probe: Callable[[], str] = field(default=lambda: "")
    orphaned: Callable[[], bool] = field(default=lambda: False)
    abandon: Callable[[], None] = field(default=lambda: None)
    live: live.LiveTicks | None = None
    stop: Callable[[int], None] | None = None  # raise the workers' stop level (live.LiveTicks.stop); None: unseen
    cancel_queued: bool = True  # a pool's queued futures cannot be cancelled safely (live's docstring)

    @property
    def max_inflight(self) -> int:
        """Batches submitted and not yet collected, at most (in-process: each runs at submit)."""
        return 1 if self.in_process else max(1, QUEUE_DEPTH * self.slots)

    @property
    def in_process(self) -> bool:
        return isinstance(self.executor, InProcessExecutor)


def _init_worker(lock_fd: int | None, shared: tuple[Any, ...] = ()) -> None:
    """Pool worker set-up: leave Ctrl-C/SIGTERM to the parent (it stops running batches through
    the live channel's stop level, or kills the workers), die with the parent, drop the inherited lock descriptor, keep the live
    channel's shared array, and import what every batch needs (:data:`WORKER_MODULES`) while
    the parent still validates the campaign."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    signal.pthread_sigmask(signal.SIG_UNBLOCK, STOP_SIGNALS)  # blocked by the parent while it forked us
    with contextlib.suppress(OSError, AttributeError):
        ctypes.CDLL(None, use_errno=True).prctl(_PR_SET_PDEATHSIG, signal.SIGKILL)
    if os.getppid() == 1:  # the parent died before prctl took effect
        os._exit(1)
    if lock_fd is not None:
        with contextlib.suppress(OSError):
            os.close(lock_fd)
    live.install(*shared)
    for module in WORKER_MODULES:
        importlib.import_module(module)


def _started() -> None:
    """The pool's first task: submitting it forks the workers (see :func:`_pool`)."""


def parse_executor_url(url: str) -> tuple[str, int]:
    """(host, port) of a Dask scheduler address ``tcp://HOST[:PORT]`` or ``tls://…``; else one line."""
    what = "must be a Dask scheduler address tcp://HOST:PORT"
    if not url.startswith(("tcp://", "tls://")):
        if url.startswith("inproc://"):
            raise InvalidParameter(
                "--executor", f"{what}: inproc:// addresses exist only inside one process, got {url!r}"
            )
        raise InvalidParameter("--executor", f"{what}, got {url!r}")
    try:
        parts = urlsplit(url)
        port = parts.port
    except ValueError as exc:
        raise InvalidParameter("--executor", f"{what}: {exc}, got {url!r}") from None
    if not parts.hostname or parts.path not in ("", "/") or parts.query or parts.fragment:
        raise InvalidParameter("--executor", f"{what} (a host is required, nothing after the port), got {url!r}")
    return parts.hostname, port or DASK_PORT


def check_executor_url(url: str | None, *, reach: bool = True) -> None:
    """Refuse a bad ``--executor`` address (exit 2) or, with ``reach``, one nobody listens on (exit 1),
    before a campaign directory is created."""
    if url is None:
        return
    host, port = parse_executor_url(url)
    if reach:
        try:
            socket.create_connection((host, port), timeout=CONNECT_TIMEOUT_S).close()
        except OSError as exc:
            raise CampaignError(f"cannot reach the Dask scheduler at {url}: {exc.strerror or exc}") from None


def _kill(processes: Any) -> None:
    """SIGKILL every live worker of a pool (``ProcessPoolExecutor._processes``, pid → Process)."""
    for process in list((processes or {}).values()):
        with contextlib.suppress(OSError, AttributeError, ValueError):
            if process.is_alive():
                process.kill()


@contextlib.contextmanager
def _stop_signals_held() -> Iterator[None]:
    """SIGINT/SIGTERM held back (pending) meanwhile: forking the workers and shutting them down
    are not cut half-way by a KeyboardInterrupt (which would leave workers nobody joins)."""
    signal.pthread_sigmask(signal.SIG_BLOCK, STOP_SIGNALS)
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_UNBLOCK, STOP_SIGNALS)


def _pool(workers: int | None, lock_fd: int | None, signals: bool = False) -> Iterator[ExecutorHandle]:
    """A fork pool whose workers are forked now (a fork pool forks every worker at its first
    submit), the stop signals held until their initializer ignores them. The runner opens it
    before its own signal handling starts and shuts it down after that ends: a Ctrl-C then
    raises KeyboardInterrupt, held until the workers are down. ``signals``: the slots carry
    their runs' signals too, for the live view (64 kB of shared memory a slot: only with it)."""
    n = workers or len(os.sched_getaffinity(0))
    context = multiprocessing.get_context("fork")
    ticks = live.LiveTicks(QUEUE_DEPTH * n, context, signals=signals)
    pool = ProcessPoolExecutor(
        max_workers=n, mp_context=context, initializer=_init_worker, initargs=(lock_fd, ticks.shared)
    )
    abandoned = False

    def abandon() -> None:
        nonlocal abandoned
        abandoned = True
        _kill(getattr(pool, "_processes", None))

    try:
        with _stop_signals_held():
            pool.submit(_started)
        yield ExecutorHandle(pool, n, abandon=abandon, live=ticks, stop=ticks.stop, cancel_queued=False)
    finally:
        with _stop_signals_held():
            processes = dict(getattr(pool, "_processes", None) or {})
            if abandoned or getattr(pool, "_broken", False):  # a broken pool SIGTERMs its workers: they ignore it
                _kill(processes)
            pool.shutdown(wait=False, cancel_futures=True)
            deadline = time.monotonic() + SHUTDOWN_S  # a worker stopped (SIGSTOP) or hung never reads its sentinel
            for process in processes.values():
                with contextlib.suppress(OSError, AttributeError, ValueError, AssertionError):
                    process.join(max(0.0, deadline - time.monotonic()))
            _kill(processes)
            pool.shutdown(wait=True)


def _workers(client: Any) -> int:
    """The workers the scheduler has now, asked of it. Not ``scheduler_info()``: it returns the
    client's cache, which the client's own periodic refresh overwrites with an empty worker list
    (it asks for none); when that refresh lands between the fetch and the return — likelier the
    busier the scheduler — it said 0 workers, and a 10^6-point campaign stopped on "Dask worker(s)
    lost (2 → 0)" while both were running."""
    return len(client.nthreads())


@contextlib.contextmanager
def _dask_quiet() -> Iterator[None]:
    """Distributed's own log records (a lost scheduler: ~30 lines of reconnection tracebacks on
    stderr) held back meanwhile: the probe finds the loss and the campaign stops in one line."""
    import logging

    loggers = [logging.getLogger(n) for n in list(logging.root.manager.loggerDict) if n.split(".")[0] == "distributed"]
    loggers.append(logging.getLogger("distributed"))
    levels = [lg.level for lg in loggers]
    for lg in loggers:
        lg.setLevel(logging.CRITICAL + 1)
    try:
        yield
    finally:
        for lg, level in zip(loggers, levels):
            lg.setLevel(level)


def _dask(url: str, workers: int | None) -> Iterator[ExecutorHandle]:
    check_executor_url(url, reach=False)
    from distributed import Client

    with _dask_quiet():
        yield from _dask_session(Client, url, workers)


def _dask_session(Client: Any, url: str, workers: int | None) -> Iterator[ExecutorHandle]:  # noqa: N803 - the class

    try:
        client = Client(url, timeout=20)
    except (OSError, TimeoutError) as exc:
        raise CampaignError(f"cannot reach the Dask scheduler at {url}: {exc}") from None
    try:
        started = _workers(client)
        slots = workers or max(1, sum(client.nthreads().values()))
        executor = client.get_executor(pure=False)
        ticks = live.LiveTicks(QUEUE_DEPTH * slots, topic=f"labrunner-live-{uuid.uuid4().hex}")
        client.subscribe_topic(ticks.topic, ticks.receive)
        lost: list[str] = []  # why the scheduler is gone, once the probe has found it

        def probe() -> str:
            if client.status != "running":
                lost.append(f"client {client.status}")
            else:
                try:
                    now = _workers(client)
                except Exception as exc:  # the scheduler went away between the status and the question
                    lost.append(type(exc).__name__)
                else:
                    return f"Dask worker(s) lost ({started} → {now})" if now < started else ""
            return f"lost the connection to the Dask scheduler at {url} ({lost[-1]})"

        def abandon() -> None:
            with contextlib.suppress(Exception):
                executor.shutdown(wait=False)
            if not lost:  # a lost scheduler has nothing left to cancel, and the call would wait for it
                with contextlib.suppress(Exception):
                    client.cancel(list(getattr(executor, "_futures", ())), force=True)

        def stop(level: int) -> None:  # every worker's copy of the level, in one round trip
            if client.status == "running":
                with contextlib.suppress(Exception):  # a lost scheduler: the probe says so
                    client.run(live.raise_level, ticks.topic, level)

        yield ExecutorHandle(
            PackedExecutor(executor),
            slots,
            probe=probe,
            orphaned=lambda: bool(lost),
            abandon=abandon,
            live=ticks,
            stop=stop,
        )
    finally:
        with contextlib.suppress(Exception):
            client.close(timeout=5)


@contextlib.contextmanager
def open_executor(
    *, real_rig: bool, workers: int | None, url: str | None, lock_fd: int | None = None, signals: bool = False
) -> Iterator[ExecutorHandle]:
    """The executor for this campaign (see the module docstring); ``signals``: a pool's workers
    share their runs' signals (the live view)."""
    if real_rig:
        yield ExecutorHandle(InProcessExecutor(), 1)
    elif url:
        yield from _dask(url, workers)
    else:
        yield from _pool(workers, lock_fd, signals)
