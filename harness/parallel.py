"""Run independent simulations side by side on a Dask cluster: one piece of code for every caller
(the verify checks' runs, the convergence study, ``cpdi sweep``).

``pmap(fn, items)`` is ``[fn(*item) for item in items]``: results in input order, and an exception
inside ``fn`` is returned as that item's value, so one failed run does not lose the others.

Where the items run:

* inside ``with cluster(jobs, scheduler):`` on that one cluster, for every pmap within it:

  - ``scheduler="tcp://host:8786"``: an existing Dask cluster (``dask scheduler`` and
    ``dask worker``, or a dask-jobqueue SLURMCluster: docs/running.md). Its workers must import
    this harness and see the same file system (the runs write their outputs there);
  - otherwise a ``LocalCluster`` of ``jobs`` worker processes (default: the cores this process
    may use), each single-threaded with ``OMP_NUM_THREADS=1``, no memory limit, quiet logs, its
    HTTP server (and dashboard, if bokeh is installed) on a free port;
  - ``jobs=1`` (or one core) without a scheduler starts no cluster: pmap runs in this process.

* outside one, pmap starts a LocalCluster for that call alone (none for one item or one core).

``submit(fn, item)`` starts one task now, ahead of the maps that follow, and ``.result()`` waits
for it: verify starts a check's longest run this way before the first check (``start_early``), so
it runs beside the other checks instead of alone at the end.

The workers are started by spawning a fresh interpreter (distributed's default), never by forking
this process: GNU OpenMP (libgomp) cannot be used in a child forked from a process that has
already run a parallel region (the child waits forever on the parent's thread pool), and the
solver is OpenMP. Each task runs the solver on the worker's ``OMP_NUM_THREADS`` threads (1 unless
the worker's environment says otherwise; distributed's nannies set 1), so ``jobs`` workers use
``jobs`` cores. Results do not depend on the thread count (bitwise, cpdi_schedule.f90).

Lost workers: a task whose worker dies while running it (killed, out of memory, a lost node) is run
again on another worker, up to ``distributed.scheduler.allowed-failures`` times (3), after which its
value is the ``KilledWorker`` error; a task whose worker leaves the cluster (a batch job's time
limit) is run again too. Each task logs its key to the scheduler, synchronously, as it starts (an
event topic per pmap call), so a task that started more than once was re-run, whatever the cause;
a task only queued on the lost worker is not counted. pmap lists them in ``Cluster.reruns``: verify
reports them (a note on the check and ``execution`` in metrics.json), ``cpdi sweep`` prints them.
Results are taken and released as they arrive, so a worker lost after finishing a task does not
make the cluster run it again.
"""

from __future__ import annotations

import asyncio
import logging
import os
import uuid
from collections import Counter
from collections.abc import Callable, Iterable, Iterator
from contextlib import contextmanager
from dataclasses import asdict, dataclass, field
from typing import Any


@dataclass
class Rerun:
    """A task that started more than once: the worker running it was lost."""

    task: str  # the function and the item's index, e.g. "_run[1]"
    runs: int  # times it started (2: re-run once)
    index: int  # the item's index in its pmap call
    context: str = ""  # what the caller was doing (verify: the check's name)


@dataclass
class Cluster:
    """Where pmap runs inside ``with cluster(...)``: ``client`` is None for the serial path."""

    mode: str  # "serial", "local" (a LocalCluster of this process) or "scheduler" (an existing cluster)
    workers: int
    client: Any = None
    address: str | None = None
    tasks: int = 0  # pmap items run
    reruns: list[Rerun] = field(default_factory=list)
    uncounted: int = 0  # tasks whose starts could not be read from the scheduler (re-runs unknown)
    context: str = ""  # set by the caller (verify: the running check), copied into each Rerun

    @property
    def serial(self) -> bool:
        return self.client is None

    def describe(self) -> str:
        if self.serial:
            return "serially in this process (no cluster)"
        n = f"{self.workers} worker{'s' * (self.workers != 1)}"
        if self.mode == "local":
            return f"a local Dask cluster of {n} (one thread each)"
        return f"the Dask scheduler at {self.address} ({n})"

    def mark(self) -> tuple[int, int, int]:
        """Where the counts stand now: summary(since=mark()) covers only what comes after."""
        return self.tasks, len(self.reruns), self.uncounted

    def summary(self, since: tuple[int, int, int] = (0, 0, 0)) -> dict[str, Any]:
        """``execution`` of metrics.json: where the runs ran, and the tasks run again after their
        worker was lost (since ``since``)."""
        reruns = self.reruns[since[1]:]
        return {"mode": self.mode, "description": self.describe(), "scheduler": self.address,
                "workers": self.workers, "tasks": self.tasks - since[0], "tasks_rerun": len(reruns),
                "reruns_uncounted": self.uncounted - since[2],
                "reruns": [asdict(r) for r in reruns]}

    def map(self, fn: Callable[..., Any], items: list[Any]) -> list[Any]:
        self.tasks += len(items)
        if self.serial or not items:
            return [_safe(fn, it) for it in items]
        from distributed import as_completed

        name = getattr(fn, "__name__", "task")
        token = uuid.uuid4().hex[:8]
        keys = [f"{name}-{token}-{i}" for i in range(len(items))]
        topic = f"cpdi-pmap-{token}"  # each task logs its key here as it starts (_task)
        futures = self.client.map(_task, [fn] * len(items), items, [topic] * len(items), key=keys)
        index = {k: i for i, k in enumerate(keys)}
        out: list[Any] = [None] * len(items)
        try:
            for f in as_completed(futures, loop=self.client.loop):
                out[index[f.key]] = _outcome(f)
                f.release()  # its result is here: a later worker death must not recompute it
        except BaseException:
            self.client.cancel(futures)
            raise
        self._count_reruns(topic, [(f"{name}[{i}]", k, i) for i, k in enumerate(keys)])
        return out

    def _count_reruns(self, topic: str, tasks: list[tuple[str, str, int]]) -> None:
        """Record the tasks (label, key, index) of one topic that started more than once."""
        starts = self._starts(topic)
        if starts is None:
            self.uncounted += len(tasks)
            return
        self.reruns += [Rerun(label, starts[k], i, self.context) for label, k, i in tasks if starts[k] > 1]

    def submit(self, fn: Callable[..., Any], item: Any, priority: float = 1.0) -> Pending:
        """fn(*item) started now, ahead of the maps that follow (a long run that would otherwise be
        the last to finish), the highest ``priority`` (> 0: before any map's task; give the run's
        estimated cost, so the longest starts first) first: its value comes from
        ``Pending.result()``. Serially, it runs then."""
        self.tasks += 1
        name = getattr(fn, "__name__", "task")
        if self.serial:
            return Pending(self, name, fn, item)
        token = uuid.uuid4().hex[:8]
        key, topic = f"{name}-{token}-early", f"cpdi-pmap-{token}"
        future = self.client.submit(_task, fn, item, topic, key=key, priority=max(int(priority), 1))
        return Pending(self, name, fn, item, future, topic, key)

    def _starts(self, topic: str) -> Counter | None:
        """How often each task of one map started (the scheduler's log of ``topic``); None if it
        cannot be read."""
        try:
            return Counter(msg for _, msg in self.client.get_events(topic))
        except Exception:
            return None


@dataclass
class Pending:
    """A task started by ``submit``; ``result()`` waits for its value (its error as the value, as
    pmap gives it) and records a re-run under the cluster's context at that time."""

    cluster: Cluster
    name: str
    fn: Callable[..., Any]
    item: Any
    future: Any = None  # None: serial, run by result()
    topic: str = ""
    key: str = ""

    def result(self) -> Any:
        c = self.cluster
        if self.future is None:
            return _safe(self.fn, self.item)
        out = _outcome(self.future)
        self.future.release()
        c._count_reruns(self.topic, [(f"{self.name}[early]", self.key, 0)])
        return out


def reruns_text(reruns: list[dict[str, Any]]) -> str:
    """``N task(s) re-run after its/their worker was lost (which, how often)`` (summary()'s reruns)."""
    n = len(reruns)
    which = ", ".join(f"{r['context'] + ': ' if r['context'] else ''}`{r['task']}` (ran {r['runs']} times)"
                      for r in reruns)
    return f"{n} task{'s' * (n != 1)} re-run after {'its' if n == 1 else 'their'} worker was lost ({which})"


def execution_text(summary: dict[str, Any]) -> str:
    """``summary()`` in one sentence, for the report and the console: where the runs ran, and
    which tasks ran again after their worker was lost."""
    text = f"{summary['description']}; {summary['tasks']} independent runs (pmap tasks)"
    if summary.get("tasks_rerun"):
        text += f"; **{reruns_text(summary['reruns'])}**; the results are complete, from the re-runs"
    if summary.get("reruns_uncounted"):
        text += f"; re-runs not known for {summary['reruns_uncounted']} tasks (the scheduler's event log not read)"
    return text


_active: Cluster | None = None
CONNECT_TIMEOUT = "10s"  # for --scheduler


def call(fn: Callable[..., Any], args: tuple) -> Any:
    """fn(*args): the task of a pmap whose items run different functions,
    ``pmap(call, [(f, (a, b)), (g, (c,)), ...])``."""
    return fn(*args)


def pmap(fn: Callable[..., Any], items: Iterable[Any], workers: int | None = None) -> list[Any]:
    """[fn(*item) for item in items] on the active cluster (see the module doc), or outside one in up
    to ``workers`` processes (default: the cores this process may use). fn must be a module-level
    function (it is pickled to the workers). Exceptions inside fn are returned as values, not
    raised, so one failed run does not lose the others."""
    items = list(items)
    if _active is not None:
        return _active.map(fn, items)
    from harness import available_cores

    with cluster(min(workers or available_cores(), len(items)) or 1) as c:
        return c.map(fn, items)


def submit(fn: Callable[..., Any], item: Any, priority: float = 1.0) -> Pending:
    """fn(*item) started now on the active cluster (Cluster.submit); outside one it runs when its
    result is asked for."""
    if _active is not None:
        return _active.submit(fn, item, priority)
    return Pending(Cluster("serial", 1), getattr(fn, "__name__", "task"), fn, item)


def active() -> Cluster | None:
    """The cluster of the innermost ``with cluster(...)``, if any."""
    return _active


@contextmanager
def cluster(jobs: int | None = None, scheduler: str | None = None) -> Iterator[Cluster]:
    """Every pmap inside runs on one cluster: the Dask scheduler at ``scheduler``, or a LocalCluster
    of ``jobs`` single-threaded worker processes (default: the cores this process may use), or, for
    ``jobs=1`` without a scheduler, serially in this process (no cluster is started). Closed on exit.
    Raises SchedulerUnreachable when no scheduler answers at ``scheduler``."""
    global _active
    from harness import available_cores

    if jobs is not None and jobs < 1:
        raise ValueError(f"jobs must be at least 1, got {jobs}")
    local = None
    if scheduler:
        client = _connect(scheduler)
        workers = len(client.scheduler_info()["workers"])
        c = Cluster("scheduler", workers, client, client.scheduler.address)
    elif (jobs or available_cores()) == 1:
        client, c = None, Cluster("serial", 1)
    else:
        local, client = _local_cluster(jobs or available_cores())
        c = Cluster("local", len(local.workers), client, local.scheduler_address)
    prev, _active = _active, c
    try:
        yield c
    finally:
        _active = prev
        if client is not None:
            client.close()
        if local is not None:
            local.close()


def _quiet() -> None:
    """distributed logs every worker start, restart and lost connection at INFO/WARNING; a worker's
    death is reported by pmap (Cluster.reruns) instead."""
    for name in ("distributed", "tornado", "asyncio"):
        logging.getLogger(name).setLevel(logging.ERROR)


class SchedulerUnreachable(OSError):
    """--scheduler names an address where no Dask scheduler answers."""


def _connect(address: str):
    from distributed import Client

    _quiet()
    try:
        return Client(address, timeout=CONNECT_TIMEOUT, set_as_default=False)
    except (OSError, TimeoutError, ValueError) as exc:
        raise SchedulerUnreachable(f"--scheduler {address}: no Dask scheduler answers there ({exc}); start the "
                                   "cluster first (docs/running.md#parallel-and-distributed-runs)") from exc


def _local_cluster(n: int):
    import dask
    from distributed import Client, LocalCluster

    _quiet()
    # worker-saturation 1: of a large map, a worker is given a task only when it has a free thread, so
    # long runs do not wait behind each other on one worker while another is free
    with dask.config.set({"distributed.scheduler.worker-saturation": 1.0}):
        local = LocalCluster(n_workers=n, threads_per_worker=1, processes=True, dashboard_address=":0",
                             silence_logs=logging.ERROR, memory_limit=0, env={"OMP_NUM_THREADS": "1"})
    return local, Client(local, set_as_default=False)


def _omp_threads() -> int:
    try:
        return max(1, int(os.environ.get("OMP_NUM_THREADS", "1").split(",")[0]))
    except ValueError:
        return 1


def _task(fn, item, topic: str):
    """One pmap item on a Dask worker: logs its start under ``topic`` (synchronously: the scheduler
    has it before the run begins, however soon the worker dies), then runs fn with the solver on the
    worker's OMP_NUM_THREADS threads."""
    from distributed import get_client, get_worker

    from harness import solver

    get_client().log_event(topic, get_worker().get_current_task())
    solver.threads(_omp_threads())
    return _safe(fn, item)


def _outcome(future):
    """A finished future's result, or its error as the value (KilledWorker after too many worker
    deaths, a cancelled task when the scheduler went away)."""
    try:
        return future.result()
    except (Exception, asyncio.CancelledError) as exc:
        return exc


def _safe(fn, item):
    try:
        return fn(*item)
    except Exception as exc:  # reported by the caller
        return exc
