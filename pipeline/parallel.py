"""Running one pure task per walk, serially or on Dask, with a progress bar fed by the results.

``evaluate`` (and anything else that treats walks independently) hands
:func:`map_walks` a function of one walk's path and a few small arguments
(the model bundle's path, the method names): nothing else travels to a
worker, so the result of a task depends only on its files, and a serial run
and a distributed run give identical results, in the input order.

- ``workers=1`` and no scheduler: a plain loop in this process (no Dask at all);
- ``workers=N`` (default: one per core): a ``dask.distributed.LocalCluster`` of
  N single-threaded worker processes (forked on Linux: :data:`_LOCAL_WORKER_CONFIG`), started and shut
  down here;
- ``scheduler="tcp://host:8786"``: an existing Dask cluster, run as whoever started it chose. The settings of
  the local cluster (:data:`_LOCAL_WORKER_CONFIG`) help it the same way; Dask reads them from its processes'
  environment: ``DASK_DISTRIBUTED__WORKER__PROFILE__ENABLED=False DASK_DISTRIBUTED__ADMIN__TICK__INTERVAL=1s
  DASK_DISTRIBUTED__ADMIN__SYSTEM_MONITOR__INTERVAL=5s DASK_DISTRIBUTED__WORKER__MEMORY__MONITOR_INTERVAL=1s
  dask worker ...`` (and the scheduler's), with the nanny's ``MALLOC_TRIM_THRESHOLD_`` left unset in a Dask
  config file (``distributed: {nanny: {pre-spawn-environ: {MALLOC_TRIM_THRESHOLD_: null}}}``; a ``DASK_``
  variable cannot name it, Dask lower-cases those names).

On Dask the walks are handed out largest first (:func:`longest_first`), the results still returned in input order.

A task that raises (an :class:`~features.errors.EnvfuseError` for bad data in
one walk, or any other exception, on this process or on a Dask worker, or a
worker that dies under it) is returned as a :class:`TaskFailure` in its place,
naming the walk and the error in one line, so one bad walk costs that walk
only and the others' results are kept.

Progress: a tqdm bar on a terminal; in a log (not a TTY) one plain line per
finished walk (``evaluate: 3/10 walks (30 %)``), never carriage-return frames.
A task that takes long (a walk of many segments: an 8-hour walk is minutes of
work) tells how far it got with :func:`task_progress`: the bar moves by the
share of the walk done, and a log gets a line at each tenth of that walk
(``evaluate: long77: 4/11 segments (36 %)``). From a Dask worker the report is
a Dask event (``Worker.log_event`` tagged with this run, on a topic the client
subscribes to: ``Client.subscribe_topic``), so it reaches this process from a
long-lived cluster too.
"""

from __future__ import annotations

import contextlib
import os
import sys
import threading
import uuid
from dataclasses import dataclass
from typing import Callable, Sequence

from features.errors import ConfigError, EnvfuseError

__all__ = ["TaskFailure", "map_walks", "task_progress", "default_workers", "check_scheduler", "local_worker_config",
           "longest_first"]


@dataclass(frozen=True)
class TaskFailure:
    """A walk whose task failed with a domain error: its path and the one-line message."""

    walk: str
    message: str


def default_workers() -> int:
    """One worker per core available to this process."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # not on Linux
        return max(1, os.cpu_count() or 1)


_LOCAL_WORKER_CONFIG = {"distributed.nanny.pre-spawn-environ.MALLOC_TRIM_THRESHOLD_": None,
                        "distributed.worker.multiprocessing-method":
                            "fork" if sys.platform.startswith("linux") else "spawn",
                        "distributed.worker.profile.enabled": False,
                        "distributed.admin.tick.interval": "1s",
                        "distributed.admin.system-monitor.interval": "5s",
                        "distributed.worker.memory.monitor-interval": "1s"}
"""The settings of the local cluster ``map_walks`` starts.

The three periodic callbacks slowed (Dask's defaults: 20 ms, 500 ms, 100 ms): every Dask server runs them on its
event loop, the scheduler and the two nannies in this process, each worker beside its task thread. Each call
wakes a thread that must take the GIL: on a worker it takes it from the task (the task thread gives it up at
the next switch interval and waits to get it back), and in this process it takes CPU from one of the two cores
the workers run on. What they are for, and why a slower pace loses nothing here: the *tick* only measures how
late the event loop runs (an INFO log line after 3 s of delay, and the dashboard's and Prometheus' latency
figures; ``distributed.admin.tick.limit`` is unchanged, so a blocked loop is still noticed within a second of
the limit); the *system monitor* samples CPU, memory, disk and network counters for the dashboard (none is
served, ``dashboard_address=None``); the *memory monitor* of each worker and nanny checks the worker's memory
against its pause (80 %) and terminate (95 %) thresholds of its limit (total memory / workers: 12 GiB each on
this 24 GiB VM against a walk's few hundred MiB): checked once a second, a worker still cannot run away from
it. Measured (``bench/bench_pipeline.py`` section 3's ``dask_overhead`` and /proc per-thread counters; 2026-12-02,
2-core VM shared with other jobs, load 4.2-5.9; a 2-worker run of the 16 evaluations of 60 s walks, main and this
setting alternated): the CPU of every process of the run outside the tasks' own threads, 3.6-7.0 s a run,
72-111 ms per second of run, with Dask's pace; 0.7-1.6 s, 19-26 ms per second, with this one (on a 17 s run on a
quiet machine: ~1.5 s -> ~0.4 s of the 34 s the two cores give); the task threads' voluntary context switches
(each a wait for the GIL) 58-109 per second -> 6-11; ``envfuse evaluate --workers 2`` as a user runs it, CPU of
all its processes 43.4 / 47.9 s -> 41.1 / 41.2 s (``--workers 1``: 35.9-37.4 s). A CPU-bound pure-Python task
alone on the cluster, per second: this process 33 -> 7.5 ms CPU, each worker's event loop 15 -> 3.4 ms and
180 -> 15 wake-ups (of the 63 ms in all, the tick 29, the memory monitors 11, the system monitors 9).

The statistical profiler off: each Dask worker samples its task thread's stack every 10 ms for the dashboard's
profile page (``distributed.worker.profile``), which takes the GIL from the task each time; no dashboard is
served here (``dashboard_address=None``), so the samples were never seen. Measured (16 evaluations of 60 s
walks, every method, two local workers, four alternated runs on this VM): 17.45-17.76 s with it, 16.63-17.38 s
without, parallel efficiency 0.81-0.83 -> 0.85.

``MALLOC_TRIM_THRESHOLD_``: Dask's nanny starts each local worker with ``MALLOC_TRIM_THRESHOLD_=65536`` so
that freed memory goes back to the OS. Setting any glibc trim threshold also switches off malloc's dynamic
mmap threshold (mallopt(3), M_TRIM_THRESHOLD), so every numpy temporary of 128 KiB or more becomes a fresh
``mmap`` that is page-faulted in and unmapped again: on four 300 s walks a worker took 184,000 minor page
faults against 1,500 in a plain process, and 0.8 s of system time. ``None`` leaves the variable unset (the
worker inherits this process's environment, so a user's own setting still holds).

The start method, ``fork`` on Linux (Dask's default is ``spawn``): a spawned worker starts a new
interpreter and imports again what a task needs (1.2-1.4 s on this VM, scipy.signal half of it) before its
first walk, and reads the model again; a forked worker starts as a copy of this process, with those imports
made and the model ``evaluate`` has just read and checked (its content hash is still checked on every walk,
:func:`pipeline.evaluate.load_model`), and the cluster starts in 0.1 s instead of 0.5 s. What makes forking
this process safe: Dask forks from a thread of its own (each worker's message-queue thread); the other
threads at that moment wait on queues and sockets (Dask's event loop, its watch threads) or are idle pools
(OpenBLAS, which re-initialises itself in the child through its pthread_atfork handlers; torch's, when a
model was trained in this process, which no worker calls: the fusion model runs on numpy and numba); numba is
used without its parallel threading layer and gtsam is built without TBB. Elsewhere (macOS, Windows) fork is
unsafe or absent and the workers are spawned. A user's own cluster (``--scheduler``) starts its workers its
own way; they keep their imports and model across runs.

A setting (other than a worker's environment variables) the user chose for Dask through its environment
variable (``DASK_DISTRIBUTED__ADMIN__TICK__INTERVAL=20ms``, ``DASK_DISTRIBUTED__WORKER__MULTIPROCESSING_METHOD=spawn``)
stands (:func:`local_worker_config`)."""


def _dask_env_name(key: str) -> str:
    """The environment variable through which Dask reads the setting ``key`` (``distributed.admin.tick.interval``
    -> ``DASK_DISTRIBUTED__ADMIN__TICK__INTERVAL``; Dask treats ``-`` and ``_`` alike)."""
    return "DASK_" + "__".join(part.upper().replace("-", "_") for part in key.split("."))


def local_worker_config() -> dict:
    """The Dask settings a local cluster of ``map_walks`` is started with (:data:`_LOCAL_WORKER_CONFIG`), less
    those the user set for Dask through its environment (``DASK_DISTRIBUTED__WORKER__MULTIPROCESSING_METHOD=spawn``):
    theirs stand."""
    return {k: v for k, v in _LOCAL_WORKER_CONFIG.items()
            if k.startswith(_PRE_SPAWN) or not os.environ.get(_dask_env_name(k))}


_PRE_SPAWN = "distributed.nanny.pre-spawn-environ."
"""Settings of a worker's environment: Dask lower-cases the names it reads from ``DASK_...`` variables, so these
are not set that way; a user sets the variable itself (``MALLOC_TRIM_THRESHOLD_``), which the worker inherits."""


def _failure(walk, exc: BaseException) -> TaskFailure:
    """One line for a failed task: the domain error's message, else the exception's type and message."""
    if isinstance(exc, EnvfuseError):
        text = str(exc)
    else:
        first = (str(exc).strip().splitlines() or [""])[0]
        text = f"internal error {type(exc).__name__}: {first}" + (" (set ENVFUSE_DEBUG=1 for a traceback)"
                                                                    if not os.environ.get("ENVFUSE_DEBUG") else "")
    return TaskFailure(str(walk), text)


_PROGRESS_TOPIC = "envfuse-progress"
"""The Dask event topic the tasks' progress goes out on, each event tagged with its run (a long-lived scheduler
keeps a topic's last events: one topic for every run, not a new one per run)."""

_REPORT = threading.local()
"""Where :func:`task_progress` sends the running task's progress (per thread: a Dask worker may run several
tasks at once): ``to`` None (nowhere), a callable (this process's bar: ``to(index, done, total)``) or a run id
(the task runs on a Dask worker); set by :func:`_guarded`."""


def task_progress(done: int, total: int) -> None:
    """Tell the bar of the :func:`map_walks` running this task that ``done`` of its ``total`` parts are done (a
    long walk's segments). Does nothing outside a task of :func:`map_walks` or with its progress off; never
    raises (a lost report costs a bar update, not the walk)."""
    to, index = getattr(_REPORT, "to", None), getattr(_REPORT, "index", 0)
    if to is None:
        return
    try:
        if callable(to):
            to(index, done, total)
        else:
            from distributed import get_worker

            get_worker().log_event(_PROGRESS_TOPIC, (to, index, int(done), int(total)))
    except Exception:  # noqa: BLE001 - progress is a courtesy; the task's result is what counts
        pass


def _guarded(func: Callable, walk, *args, report=None):
    """``func(walk, *args)``, its failure returned as a :class:`TaskFailure`; ``report``: (where, index) for
    :func:`task_progress` while it runs (where: a callable or a run id for Dask events)."""
    import warnings

    _REPORT.to, _REPORT.index = report if report is not None else (None, 0)
    try:
        with warnings.catch_warnings():
            # numpy's RuntimeWarnings (empty slices, all-NaN windows) are not for the user's terminal; what
            # matters reaches the report as NaN rows or notes
            warnings.simplefilter("ignore", RuntimeWarning)
            return func(walk, *args)
    except Exception as exc:  # noqa: BLE001 - one walk's failure must not cost the others (named in the report)
        if os.environ.get("ENVFUSE_DEBUG") and not isinstance(exc, EnvfuseError):
            import traceback

            traceback.print_exc()
        return _failure(walk, exc)
    finally:
        _REPORT.to, _REPORT.index = None, 0


class _Progress:
    """A tqdm bar on a terminal; in a log (stderr not a TTY) one plain line per finished walk,
    ``evaluate: 2/5 walks (40 %)``, never carriage-return frames. A task's share done (:meth:`part`) moves the bar
    by that share of one walk, and in a log prints a line at each tenth of that walk's parts,
    ``evaluate: long77: 4/11 segments (36 %)``. Thread-safe: on Dask the parts arrive on the client's event
    loop thread while the walks' results arrive on this one."""

    def __init__(self, total: int, desc: str, enabled: bool, names: Sequence[str] = ()):
        self.total, self.desc, self.enabled, self.n = total, desc, enabled, 0
        self.names = list(names)
        self.bar = None
        self.credited: dict[int, float] = {}     # per unfinished walk: the share of it the bar shows
        self.tenth: dict[int, int] = {}          # per walk: the last tenth of its parts a log line told
        self.finished: set[int] = set()
        self.lock = threading.Lock()
        if enabled and sys.stderr.isatty():
            from tqdm import tqdm

            self.bar = tqdm(total=total, desc=desc, unit="walk", file=sys.stderr, leave=False,
                            bar_format="{l_bar}{bar}| {n:.1f}/{total} walks [{elapsed}<{remaining}]")

    def part(self, i: int, done: int, total: int) -> None:
        """Walk ``i``'s task has done ``done`` of its ``total`` parts."""
        if not self.enabled or total <= 0:
            return
        with self.lock:
            if i in self.finished:
                return                               # a report that arrived after the walk's result
            share = min(max(done / total, 0.0), 1.0)
            if self.bar is not None:
                if share > self.credited.get(i, 0.0):
                    self.credited[i] = share
                    self._show()
                return
            tenth = int(10 * done // total)
            if tenth > self.tenth.get(i, 0):
                self.tenth[i] = tenth
                name = self.names[i] if i < len(self.names) else f"walk {i + 1}"
                print(f"{self.desc}: {name}: {done}/{total} segments ({100 * share:.0f} %)", file=sys.stderr,
                      flush=True)

    def done(self, i: int) -> None:
        """Walk ``i``'s result is in."""
        with self.lock:
            self.finished.add(i)
            self.n += 1
            if self.bar is not None:
                self.credited.pop(i, None)
                self._show()
            elif self.enabled:
                print(f"{self.desc}: {self.n}/{self.total} walks ({100 * self.n / max(self.total, 1):.0f} %)",
                      file=sys.stderr, flush=True)

    def _show(self) -> None:
        """The bar at the walks finished plus the shares of those running (set, not summed: no float drift)."""
        self.bar.n = self.n + sum(self.credited.values())
        self.bar.refresh()

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()


def _names(walks: Sequence) -> list[str]:
    """How the progress lines name the walks: their folders' names, or their paths as given where two share a
    name (walk01 of two sites)."""
    paths = [os.path.normpath(str(w)) for w in walks]
    names = [os.path.basename(p) for p in paths]
    return names if len(set(names)) == len(names) else paths


def _progress_bar(total: int, desc: str, enabled: bool, names: Sequence[str] = ()) -> _Progress:
    return _Progress(total, desc, enabled, names)


def map_walks(func: Callable, walks: Sequence, *args, workers: int | None = None, scheduler: str | None = None,
              progress: bool = True, desc: str = "walks") -> list:
    """``[func(walk, *args) for walk in walks]``, serially or on Dask; results in input order.

    ``func`` must be importable by name (a module-level function) when run on Dask.
    """
    walks = list(walks)
    if workers is not None and workers < 1:
        raise ConfigError(f"--workers must be at least 1, got {workers}")
    if not walks:
        return []
    client_address = check_scheduler(scheduler) if scheduler is not None else None
    bar = _progress_bar(len(walks), desc, progress, _names(walks))
    try:
        if scheduler is None and (workers == 1 or (workers is None and default_workers() == 1) or len(walks) == 1):
            out = []
            for i, w in enumerate(walks):
                out.append(_guarded(func, w, *args, report=(bar.part, i) if progress else None))
                bar.done(i)
            return out
        return _map_dask(func, walks, args, workers, client_address, bar)
    finally:
        bar.close()


def check_scheduler(address: str, timeout_s: float = 3.0) -> str:
    """A Dask scheduler address checked before any work: ``tcp://host:port`` (or ``host:port``, or ``tls://``)
    that accepts a connection within ``timeout_s`` — a malformed address is a usage error (exit 2), a refused
    or silent port a :class:`~features.errors.ConfigError` at once, not after the client's 10 s wait."""
    import re
    import socket

    from pipeline.args import UsageError

    m = re.fullmatch(r"(?:(tcp|tls)://)?(\[[0-9A-Fa-f:.]+\]|[A-Za-z0-9_.-]+):(\d{1,5})", str(address).strip())
    if m is None or not 0 < int(m.group(3)) < 65536:
        raise UsageError(f"--scheduler {address!r}: expected a Dask scheduler address such as tcp://host:8786")
    scheme, host, port = m.group(1) or "tcp", m.group(2).strip("[]"), int(m.group(3))
    try:
        with socket.create_connection((host, port), timeout=timeout_s):
            pass
    except OSError as exc:
        raise ConfigError(f"--scheduler {address}: cannot connect ({exc.strerror or exc})") from None
    return f"{scheme}://{m.group(2)}:{port}"


def _bytes_on_disk(walk) -> int:
    """A walk's size, what its task's time grows with: the bytes of a file, or of the files in a walk folder (its
    audio is most of it); 0 for anything else."""
    try:
        if os.path.isdir(walk):
            with os.scandir(walk) as entries:
                return sum(e.stat().st_size for e in entries if e.is_file())
        return os.path.getsize(walk)
    except (OSError, TypeError, ValueError):
        return 0


def longest_first(walks: Sequence) -> list[int]:
    """Indices of ``walks``, largest on disk first (ties in input order): the order their tasks are handed to the
    workers in.

    Graham's LPT rule (longest processing time first; R. L. Graham, "Bounds on multiprocessing timing
    anomalies", SIAM J. Appl. Math. 17(2), 1969): each free worker takes the longest task left, so the shortest
    come last and the run ends within one short task of the other workers, where input order could leave one
    worker on an 8-hour walk while the others idle. Only the order of work changes: each result is a function of
    its walk alone and is put back in its input place."""
    sizes = [_bytes_on_disk(w) for w in walks]
    return sorted(range(len(walks)), key=lambda i: -sizes[i])


def _map_dask(func, walks, args, workers, scheduler, bar) -> list:
    import logging

    import dask
    from distributed import Client, LocalCluster, as_completed

    logging.getLogger("distributed").setLevel(logging.ERROR)
    cluster = None
    if scheduler is None:
        n = workers or default_workers()
        # the local cluster's log: CRITICAL only, its workers' and (silence_logs sets the "distributed" loggers'
        # level in this process too) its scheduler's and nannies'. At shutdown a worker's heartbeat can meet the
        # scheduler's closed socket and Dask logs that at ERROR with a traceback (seen once in ~20 cluster
        # shutdowns of bench/bench_pipeline.py --evaluate-only); a task's error or a worker's death (killed for
        # memory, crashed) reaches this process as the future's exception and is reported as a TaskFailure, so
        # nothing a user needs goes unsaid
        with dask.config.set(local_worker_config()):
            cluster = LocalCluster(n_workers=min(n, len(walks)), threads_per_worker=1, processes=True,
                                   dashboard_address=None, silence_logs=logging.CRITICAL)
        client = Client(cluster)
    else:
        try:
            client = Client(scheduler, timeout="10s")
        except (OSError, TimeoutError, ValueError) as exc:
            raise ConfigError(f"--scheduler {scheduler}: cannot connect ({exc})") from None
    run = None
    try:
        if bar.enabled:     # the tasks' progress: Dask events tagged with this run (module docstring)
            run = uuid.uuid4().hex

            def on_event(event) -> None:
                try:
                    tag, i, done, total = event[1]
                except (TypeError, ValueError):
                    return                      # not one of ours: a courtesy channel never raises
                if tag == run:                  # another run's on a shared cluster: not this bar's
                    bar.part(i, done, total)
            client.subscribe_topic(_PROGRESS_TOPIC, on_event)
        # longest first (LPT); the priority makes the scheduler hand them out in that order, not only receive them
        order = longest_first(walks)
        futures = [client.submit(_guarded, func, walks[i], *args, key=f"walk-{i}-{os.path.basename(str(walks[i]))}",
                                 pure=False, priority=len(walks) - rank,
                                 report=(run, i) if run is not None else None)
                   for rank, i in enumerate(order)]
        index = {f.key: i for f, i in zip(futures, order)}
        out = [None] * len(walks)
        for fut in as_completed(futures):
            i = index[fut.key]
            try:
                out[i] = fut.result()
            except Exception as exc:  # noqa: BLE001 - a worker died under the task (KilledWorker, lost data)
                out[i] = _failure(walks[i], exc)
            bar.done(i)
        return out
    finally:
        if run is not None:
            with contextlib.suppress(Exception):       # a client already closed (scheduler lost) must not hide
                client.unsubscribe_topic(_PROGRESS_TOPIC)   # what went wrong, nor skip the closes below
        client.close()
        if cluster is not None:
            cluster.close()
