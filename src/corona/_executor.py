"""Runs independent tasks in this process or on a Dask cluster (shared infrastructure).

One :class:`Executor` runs the sweeps' renders (:mod:`corona.apps.sweep`), the validation's
cases (:mod:`corona.reference.validate`), the reference tier's table rows and the gallery:

* ``workers=0``: in this process, one task after the other (no Dask needed);
* no ``scheduler``: a ``distributed.LocalCluster`` on this machine, one worker process per
  task slot, each running one task at a time, with Dr.Jit's thread pool set to
  ``cores // workers_on_the_host`` (applied by :mod:`corona.apps.sweep` before a render);
* ``scheduler="tcp://host:8786"``: an existing Dask cluster.

It sits below every tier (it imports only :mod:`corona._validation`), so the reference tier
and the applications share it without an import from one into the other.  Dask's
``distributed`` is the ``sweep`` extra; ``import corona`` never imports it.
"""
from __future__ import annotations

import collections
import dataclasses
import logging
import os
import socket
import threading
import time

from corona._validation import CoronaError, one_line_error

#: Default seconds to wait for a scheduler (connection) and its first worker.
TIMEOUT = 10.0
#: Longest accepted wait for a scheduler and its first worker [s] (a day; 1e308 overflowed the clock).
TIMEOUT_MAX = 86400.0


# ==========================================================================
# the executor
# ==========================================================================
@dataclasses.dataclass
class Outcome:
    """The result of one task: ``value``, or ``error`` (a one-line message)."""
    index: int
    label: str
    value: object = None
    error: str | None = None

    @property
    def ok(self) -> bool:
        return self.error is None


def _cpus() -> int:
    try:
        return len(os.sched_getaffinity(0))
    except (AttributeError, OSError):   # pragma: no cover - not Linux
        return os.cpu_count() or 1


def _memory_bytes() -> int | None:
    try:
        import psutil   # a dependency of distributed
        return int(psutil.virtual_memory().total)
    except Exception:  # noqa: BLE001  pragma: no cover
        return None


def default_workers(n_tasks: int | None = None) -> int:
    """Local cluster size: one worker per core, at most one per task and one per
    GiB of memory (a render holds a scene and its wavefronts)."""
    n = _cpus()
    mem = _memory_bytes()
    if mem:
        n = min(n, max(1, mem // 2**30))
    if n_tasks:
        n = min(n, n_tasks)
    return max(1, int(n))


#: per worker process: the Dr.Jit thread count it was given and the variant it set
WORKER: dict = {}
_JOB_LOCK = threading.Lock()      # one job at a time per process, whatever the worker's nthreads


def _configure_worker(workers_on_host: dict, dask_worker=None) -> int:
    """Run on every worker once: its Dr.Jit thread count, cores // workers on its host
    (applied before its first render, :func:`_prepare_renderer`)."""
    n = int(workers_on_host.get(getattr(dask_worker, "address", None), 1))
    WORKER["threads"] = max(1, _cpus() // max(1, n))
    return WORKER["threads"]


#: The address schemes of a Dask scheduler (``distributed.comm``) that a sweep connects to.
DASK_SCHEMES = ("tcp", "tls", "ws", "wss", "ucx")
#: Most local workers per core (``--workers N`` beyond it, or beyond the number of points, is capped).
WORKERS_PER_CORE = 2


def _within(seconds: float, fn, what: str):
    """``fn()`` in a daemon thread, abandoned after ``seconds`` (CoronaError ``what``): Dask's Client
    waits without end for a peer that accepts the connection and never answers its handshake."""
    box = {}

    def go():
        try:
            box["value"] = fn()
        except BaseException as err:  # noqa: BLE001 - handed to the caller
            box["error"] = err
    t = threading.Thread(target=go, name="corona-sweep-connect", daemon=True)
    t.start()
    t.join(seconds)
    if t.is_alive():
        raise CoronaError(what)
    if "error" in box:
        raise box["error"]
    return box["value"]


def _probe(address: str, timeout: float) -> str:
    """Check that something listens at a ``tcp://`` scheduler address (fast, one line on failure)."""
    from distributed.comm.addressing import parse_address, parse_host_port, unparse_address
    try:
        scheme, loc = parse_address(address)
        if scheme not in DASK_SCHEMES:
            raise CoronaError(f"--scheduler {address!r} is not a Dask scheduler address (scheme "
                              f"{scheme}://); expected {' or '.join(s + '://' for s in DASK_SCHEMES)}HOST:PORT, "
                              "e.g. tcp://127.0.0.1:8786")
        if scheme != "tcp":
            return address        # tls://, ...: let Dask connect
        host, port = parse_host_port(loc, 8786)
    except CoronaError:
        raise
    except ValueError as err:
        raise CoronaError(f"--scheduler {address!r} is not a scheduler address ({err}); expected "
                          "tcp://HOST:PORT, e.g. tcp://127.0.0.1:8786") from None
    try:
        with socket.create_connection((host, port), timeout=timeout):
            pass
    except OSError as err:
        why = "no answer" if isinstance(err, TimeoutError) else (err.strerror or str(err))
        raise CoronaError(f"--scheduler {address!r}: no Dask scheduler reachable at {host}:{port} "
                          f"within {timeout:g} s ({why}); start one with `dask scheduler` "
                          "or leave out --scheduler for a local cluster") from None
    return unparse_address("tcp", f"{host}:{port}")


class Executor:
    """Runs independent tasks in this process or on a Dask cluster.

    Parameters
    ----------
    workers : int, optional
        ``0``: in this process, no Dask.  ``N > 0``: a local cluster of ``N``
        worker processes.  ``None`` (default): a local cluster sized by
        :func:`default_workers` — unless ``scheduler`` is given.
    scheduler : str, optional
        Address of an existing Dask scheduler (``tcp://host:8786``).
    timeout : float
        Seconds to wait for the scheduler and for its first worker.

    The cluster starts at the first :meth:`map` (so bad input found before
    it costs no start-up) and stops at :meth:`close` / the end of a ``with``.
    """

    def __init__(self, workers: int | None = None, scheduler: str | None = None, *,
                 timeout: float = TIMEOUT, log=None):
        if workers is not None and scheduler is not None:
            raise CoronaError("--workers and --scheduler exclude each other: --workers N starts a local "
                              "cluster, --scheduler ADDRESS uses an existing one")
        if workers is not None and (int(workers) != workers or workers < 0):
            raise CoronaError(f"workers={workers!r} is out of range; expected an integer >= 0 "
                              "(0: in this process)")
        if isinstance(timeout, bool) or not isinstance(timeout, (int, float)) or not (0 < timeout <= TIMEOUT_MAX):
            raise CoronaError(f"timeout={timeout!r} is out of range; allowed a finite number of seconds "
                              f"in (0, {TIMEOUT_MAX:g}]")
        if scheduler is not None and "://" in str(scheduler):
            scheme = str(scheduler).split("://", 1)[0].lower()
            if scheme not in DASK_SCHEMES:       # before anything is imported or started
                raise CoronaError(f"--scheduler {scheduler!r} is not a Dask scheduler address (scheme "
                                  f"{scheme}://); expected {' or '.join(s + '://' for s in DASK_SCHEMES)}"
                                  "HOST:PORT, e.g. tcp://127.0.0.1:8786")
        self.workers = None if workers is None else int(workers)
        self.scheduler = scheduler
        self.timeout = float(timeout)
        self.log = log or (lambda s: None)
        self.client = None
        self.cluster = None
        self.threads = {}          # worker address -> Dr.Jit threads
        self.startup_seconds = 0.0

    # -- life cycle ---------------------------------------------------------
    @property
    def in_process(self) -> bool:
        return self.workers == 0

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def start(self, n_tasks: int | None = None) -> "Executor":
        """Start (or connect to) the cluster; nothing when in process or already started."""
        if self.in_process or self.client is not None:
            return self
        try:
            import distributed
        except ImportError:
            raise CoronaError("running on a Dask cluster needs the 'sweep' extra: pip install "
                              "'corona-bsdf[sweep]' (or --workers 0: one job after the other in this "
                              "process)") from None
        t0 = time.perf_counter()
        if self.scheduler is not None:
            address = _probe(self.scheduler, self.timeout)
            try:
                self.client = _within(
                    self.timeout,
                    lambda: distributed.Client(address, timeout=self.timeout, set_as_default=False),
                    f"--scheduler {self.scheduler!r} accepted the connection but did not answer as a Dask "
                    f"scheduler within {self.timeout:g} s; is it one (`dask scheduler`)?")
            except CoronaError:
                raise
            except (OSError, TimeoutError, ValueError) as err:
                raise CoronaError(f"--scheduler {self.scheduler!r}: could not connect within "
                                  f"{self.timeout:g} s ({' '.join(str(err).split())})") from None
            try:
                self.client.wait_for_workers(1, timeout=self.timeout)
            except (TimeoutError, OSError):
                self.close()
                raise CoronaError(f"--scheduler {self.scheduler!r} has no workers (waited "
                                  f"{self.timeout:g} s); start some with `dask worker "
                                  f"{self.scheduler}`") from None
        else:
            n = self.workers or default_workers(n_tasks)
            cap = max(1, min(n_tasks or n, WORKERS_PER_CORE * _cpus()))
            if n > cap:
                self.log(f"corona: --workers {n} capped to {cap} ({n_tasks} job(s), {_cpus()} core(s), "
                         f"at most {WORKERS_PER_CORE} workers per core)")
                n = cap
            self.cluster = distributed.LocalCluster(
                n_workers=n, threads_per_worker=1, processes=True, host="127.0.0.1",
                dashboard_address=None, silence_logs=logging.CRITICAL)
            self.client = distributed.Client(self.cluster, set_as_default=False)
        workers = self.client.scheduler_info(n_workers=-1)["workers"]
        per_host = collections.Counter(w["host"] for w in workers.values())
        plan = {addr: per_host[w["host"]] for addr, w in workers.items()}
        self.threads = self.client.run(_configure_worker, plan)
        self.startup_seconds = time.perf_counter() - t0
        self.log(f"corona: {self.describe()} (started in {self.startup_seconds:.1f} s)")
        return self

    def describe(self) -> str:
        if self.in_process:
            return "in this process"
        if self.client is None:
            return "cluster not started"
        n = len(self.threads)
        th = sorted(set(self.threads.values()))
        where = f"scheduler {self.scheduler}" if self.scheduler else "local cluster"
        return (f"{where}: {n} worker(s), one job at a time each, "
                f"{'/'.join(map(str, th))} Dr.Jit thread(s) per worker")

    def close(self) -> None:
        for obj in (self.client, self.cluster):
            if obj is not None:
                try:
                    obj.close()
                except Exception:  # noqa: BLE001  (shutting down: nothing left to report)
                    pass
        self.client = self.cluster = None

    # -- running ------------------------------------------------------------
    def map(self, fn, tasks, labels=None, *, desc: str = "tasks", progress: bool = True,
            on_result=None) -> list:
        """Run ``fn(*args)`` for every ``args`` of ``tasks``; a list of :class:`Outcome` in task order.

        A failing task gives an ``Outcome`` with ``error`` (one line) and the
        others still run.  ``on_result(outcome)`` is called in this process as
        each task finishes (in completion order), e.g. to write its files.
        ``fn`` must be importable on the workers (a module-level function of
        an installed package).
        """
        from tqdm import tqdm

        tasks = [tuple(t) for t in tasks]
        labels = list(labels) if labels is not None else [str(i) for i in range(len(tasks))]
        out = [None] * len(tasks)
        if not tasks:
            return out
        self.start(len(tasks))
        bar = tqdm(total=len(tasks), desc=desc, unit="job", disable=not progress, dynamic_ncols=True)

        def finish(o: Outcome):
            out[o.index] = o
            if on_result is not None:
                on_result(o)
            if not o.ok:
                bar.write(f"corona: {desc} {o.label}: FAILED: {o.error}")
            bar.update(1)

        try:
            if self.in_process:
                for i, args in enumerate(tasks):
                    ok, value = _run_job(fn, args)
                    finish(Outcome(i, labels[i], value=value) if ok else Outcome(i, labels[i], error=value))
            else:
                import distributed
                futures = {}
                for i, args in enumerate(tasks):
                    fut = self.client.submit(_run_job, fn, args, pure=False, retries=0)
                    futures[fut] = i
                for fut in distributed.as_completed(list(futures), loop=self.client.loop):
                    i = futures[fut]
                    try:
                        ok, value = fut.result()
                        o = Outcome(i, labels[i], value=value) if ok else Outcome(i, labels[i], error=value)
                    except Exception as err:  # noqa: BLE001  (a worker died, a task was lost)
                        o = Outcome(i, labels[i], error=one_line_error(err))
                    fut.release()
                    finish(o)
        finally:
            bar.close()
        return out


def _run_job(fn, args):
    """One task on a worker (or here), one job at a time per process:
    ``(True, value)`` or ``(False, one-line error)`` (the worker logs nothing)."""
    with _JOB_LOCK:
        try:
            return True, fn(*args)
        except Exception as err:  # noqa: BLE001  (reported with the task's label)
            return False, one_line_error(err)
