"""Rendering on a Dask cluster with the same image as a local render.

The cluster runs exactly the tasks the local process pool runs (groups of
tile x pass units, :func:`wavefront.render.execute`), and the client merges
their results in task order.  Since a unit's samples depend only on the seed
and the unit, and the merge order is fixed, the image is bit-identical to a
local render whatever the number of workers, and a worker that dies only
costs the tasks it held: Dask reschedules them and their results are the same.

The scene travels once per worker: it is scattered with ``broadcast=True`` and
each worker compiles it once (cached by a token), not once per task.

Dask itself is imported only when ``--scheduler`` is given (and logging and
uuid only with it: ``import wavefront`` imports this module, and every command
would pay for them).
"""

from __future__ import annotations

import sys

from .memory import MemoryBudgetError, MiB, current_rss, over_budget, release_free_memory
from .render import (FILM_BYTES_PER_PIXEL, POLL_SECONDS, TASKS_IN_FLIGHT, RenderInterrupted, execute,
                     plan_local_workers, tune_allocator)
from .sampling import scene_key
from .validation import first_line

CONNECT_TIMEOUT = "5s"  # an address that does not answer is reported within seconds
# A local Dask worker is a process of its own: 61-63 MiB at rest, measured
# (interpreter, NumPy, Dask), and ~7 MiB more once it has imported wavefront,
# before it holds a scene or a wavefront.
LOCAL_WORKER_BYTES = 80 * 1024 * 1024  # (and some room: the tree peaked 204 MiB under 200M at 72)
# ... and a LocalCluster adds to the parent: Dask's modules (~45 MiB) and
# multiprocessing's resource tracker, a process of its own (~12 MiB).
LOCAL_CLUSTER_BYTES = 64 * 1024 * 1024
LOCAL_TRACKER_BYTES = 16 * 1024 * 1024
# What Dask adds to this process, estimated before the cluster starts so that a
# render the planner will refuse is refused first: importing dask.distributed
# measured +26 MiB, starting a LocalCluster +2 MiB (Dask 2026.8).  Kept at the
# low end, unlike LOCAL_CLUSTER_BYTES: the planner measures this process once
# the cluster runs and has the last word, so an estimate too low only starts a
# cluster the planner then refuses, while one too high would refuse renders
# that fit.
DASK_CLIENT_BYTES = 24 * 1024 * 1024


class SchedulerError(ConnectionError):
    """The scheduler could not be reached or started."""


def connect(scheduler: str, memory: int | None = None):
    """A ``Client`` for ``tcp://host:port`` or ``local:N`` (a LocalCluster of
    N processes, at most as many as ``memory`` bytes hold: see
    :func:`local_worker_count`).  Anything that goes wrong while connecting
    is a :class:`SchedulerError` (a port answering in another protocol made
    Dask try to allocate 3 EiB)."""
    try:
        from dask.distributed import Client, LocalCluster
    except ImportError:
        raise SchedulerError("Dask is not installed: pip install 'wavefront[distributed]'") from None
    n = local_worker_count(scheduler, memory)
    if n:
        import logging

        cluster = LocalCluster(n_workers=n, threads_per_worker=1, processes=True,
                               dashboard_address=None, silence_logs=logging.ERROR)
        return Client(cluster)
    try:
        return Client(scheduler, timeout=CONNECT_TIMEOUT)
    except Exception as e:  # noqa: BLE001 (Dask's comm layers raise many types: TypeError for tls:// without a context)
        raise SchedulerError(f"{scheduler}: cannot connect to the Dask scheduler ({first_line(e)})") from None


def local_worker_count(scheduler: str, memory: int | None = None) -> int:
    """N for ``local:N``, else 0 (an address).

    With ``memory``, a :class:`SchedulerError` unless N workers at
    ``LOCAL_WORKER_BYTES`` each and the cluster's ``LOCAL_CLUSTER_BYTES`` fit
    beside what this process holds (with Dask's modules, ``DASK_CLIENT_BYTES``,
    when they are not imported yet): checked before the cluster starts, since
    its processes are in the budget (``local:99999999999999999999`` grew to
    14 GB building Dask's table of workers)."""
    if not scheduler.startswith("local:"):
        return 0
    try:
        n = int(scheduler.split(":", 1)[1])
        if n < 1:
            raise ValueError
    except ValueError:
        raise SchedulerError(f"{scheduler}: expected local:N with N >= 1 workers") from None
    if memory is not None:
        # Checked once before Dask is imported (the CLI, so that a cluster that
        # cannot fit is refused at once) and again in connect, after: its
        # modules counted in both, or the first check's "at most local:N"
        # (37-39 MiB held) was refused by the second (63-64 MiB).
        importing = 0 if "dask.distributed" in sys.modules else DASK_CLIENT_BYTES
        held = current_rss() + importing
        need = n * LOCAL_WORKER_BYTES + LOCAL_CLUSTER_BYTES
        if held + need > memory:
            fits = max(0, (memory - held - LOCAL_CLUSTER_BYTES) // LOCAL_WORKER_BYTES)
            total, budget = over_budget(held + need, memory)
            raise SchedulerError(
                f"{scheduler}: {n} local worker{'s' if n > 1 else ''} need{'' if n > 1 else 's'} at least "
                f"{LOCAL_WORKER_BYTES // MiB} MiB{' each' if n > 1 else ''} and the cluster "
                f"{LOCAL_CLUSTER_BYTES // MiB} MiB beside the {held / MiB:,.0f} MiB this process holds"
                f"{' with Dask imported' if importing else ''}: "
                f"{total} in all, more than the memory budget of {budget} "
                "(--memory); " + (f"at most local:{fits}" if fits else "a local cluster does not fit in it"))
    return n


def refuse_unless_local_render_fits(scheduler: str, scene, memory: int, *, chunk_size: int | None = None,
                                    output_bytes: int | None = None) -> None:
    """Before ``local:N``'s cluster starts: refuse (:class:`MemoryBudgetError`)
    a render that the plan made once it runs would refuse, with this
    process's memory as it is now and Dask's (its modules here,
    ``DASK_CLIENT_BYTES``, and its tracker, ``LOCAL_TRACKER_BYTES``)
    estimated.  A film-heavy render started the cluster (~140 MiB, seconds)
    only to be refused by the planner.  The film is counted even when
    resuming: the checkpoint's is not loaded yet."""
    n = local_worker_count(scheduler)
    if not n:
        return
    pixels = scene.width * scene.height
    release_free_memory()  # as render_scene does before it measures: loading's garbage is not held
    try:
        plan_local_workers(scene, memory, n, chunk_size, held=current_rss(),
                           cluster=DASK_CLIENT_BYTES + LOCAL_TRACKER_BYTES,
                           worker_bytes=LOCAL_WORKER_BYTES, film=pixels * FILM_BYTES_PER_PIXEL,
                           output=pixels * 3 * 4 if output_bytes is None else output_bytes)
    except MemoryBudgetError as e:
        raise MemoryBudgetError(f"{scheduler}: {e}") from None


_COMPILED: dict = {}


def _remote_execute(scene, token: str, capacity: int, units):
    """Runs on a worker: compile the scene once per token, then render the units."""
    if _COMPILED.get("token") != token:
        # Dask's nanny starts workers with MALLOC_TRIM_THRESHOLD_=65536, which
        # hands every wavefront temporary back to the kernel: measured 6x slower.
        tune_allocator()
        _COMPILED.clear()
        _COMPILED.update(token=token, compiled=scene.compile(), key=scene_key(scene.render.seed))
    return execute(_COMPILED["compiled"], _COMPILED["key"], capacity, units)


def dask_executor(client, local_workers: int = 0):
    """An ``executor`` for :func:`wavefront.render.render_scene` running on ``client``.

    ``local_workers``: the client's cluster is a LocalCluster of that many
    processes (see :func:`connect`), which are in this process tree: the
    render plans its memory budget for them (their peaks come back with
    their tasks' results, as a process pool's do)."""
    from dask.distributed import wait

    def run(scene, capacity, tasks, merge, stopped):
        import uuid

        token = uuid.uuid4().hex  # names this render's tasks and its cached scene
        scene_future = client.scatter(scene, broadcast=True, hash=False)
        # A window of tasks in flight, a few per worker, refilled as results
        # are merged: the plan is never materialised, however long it is.
        window = TASKS_IN_FLIGHT * max(1, len(client.scheduler_info().get("workers", {})))
        tasks = enumerate(tasks)
        index, remaining, pending, next_index = {}, set(), {}, 0

        def submit() -> None:
            for i, units in tasks:
                future = client.submit(_remote_execute, scene_future, token, capacity, units,
                                       key=f"wavefront-{token}-{i}", pure=False)
                index[future.key] = i
                remaining.add(future)
                return

        try:
            for _ in range(window):
                submit()
            while remaining:
                if stopped():
                    raise RenderInterrupted
                try:
                    done, _ = wait(list(remaining), timeout=POLL_SECONDS, return_when="FIRST_COMPLETED")
                except TimeoutError:
                    continue
                for future in done:
                    remaining.discard(future)
                    pending[index.pop(future.key)] = future.result()  # re-raises a task's error
                while next_index in pending:  # merge strictly in task order
                    merge(pending.pop(next_index))
                    next_index += 1
                    submit()
        finally:
            client.cancel(list(remaining))
            client.cancel(scene_future)

    # what render_scene plans for: the workers, and beside this process (whose own
    # resident memory already holds Dask's modules) the resource tracker
    run.local_workers, run.worker_bytes, run.cluster_bytes = local_workers, LOCAL_WORKER_BYTES, LOCAL_TRACKER_BYTES
    return run
