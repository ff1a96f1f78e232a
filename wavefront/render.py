"""The render driver: tasks of units, the memory budget, the process pool.

The render is a fixed plan of units (:mod:`wavefront.units`) grouped into
tasks of a few wavefronts' worth of samples.  Tasks run inline or on a process
pool; their results are merged into the film (:mod:`wavefront.film`) in task
order, so the image does not depend on the worker count, and the chunk size
(wavefront capacity) only decides how many paths are in flight, never which
random numbers a path sees.

Memory: the budget covers the whole process tree.  Before rendering, the
parent measures what it holds (interpreter, modules, the compiled scene and
its acceleration structure), adds the film, each worker's share (a forked
worker's resident set starts as the parent's) and the cost of writing the
image, and picks the number of workers and the wavefront size to fit, or
refuses with the estimate (:func:`plan_memory`).  Tasks are planned lazily
and only a few are in flight, so nothing grows with the sample count.
"""

from __future__ import annotations

import itertools
import os
import signal
import threading
import time
import warnings
from dataclasses import dataclass, field
from functools import cached_property

import numpy as np

from .film import CheckpointError, FILM_BYTES_PER_PIXEL, Film, load_checkpoint, save_checkpoint  # noqa: F401 (CheckpointError re-exported)
from .integrators import STREAMING, TRACERS
from .memory import (  # noqa: F401 (MemoryBudgetError and the measures are part of this module's API)
    MemoryBudgetError, check_budget, current_rss, libc, over_budget, peak_rss, phase_peak, physical_memory,
    refuse_unless_fits, release_free_memory, reserve_heap)
from .output import OutputError, check_output_path
from .path import HELD_TASKS, TaskStream, TraceStats
from .sampling import scene_key
from .scene import CompiledScene, Scene
from .units import Job, Unit, UnitPlan, plan_units
from .validation import first_line

MiB = 1024 * 1024
DEFAULT_MEMORY = 1024 * MiB  # whole render, all processes
# Measured bytes per path in flight, the batch, every per-bounce temporary and
# the task's per-sample radiance included; see ``benchmarks/bench.py --section capacity``.
BYTES_PER_PATH = 1500
MAX_CAPACITY = 1 << 16  # larger wavefronts fall out of cache and get slower
MIN_CAPACITY = 256  # below this NumPy's fixed cost per call dominates
# Below this many paths in flight a worker is not worth its share of the
# budget (each costs a copy of the parent's resident set): use fewer workers.
GOOD_CAPACITY = 4096
TASK_WAVEFRONTS = 4  # a task holds about this many wavefronts' samples
# A render is shared out below a wavefront per task only down to this many
# samples a task: starting a pool of forked workers costs about as much as
# rendering ~10k samples of a small scene on one core (128x128 at 1 spp ran
# no faster on two workers than inline).
SMALLEST_SHARED_TASK = 1 << 14
# Out per worker: running, or finished and waiting for an earlier one to be
# merged (a Dask worker runs one task at a time).
TASKS_IN_FLIGHT = 2
# Out per pool worker of a streaming integrator (see path.hand_over): in its
# wavefront (up to path.HELD_TASKS), or finished and waiting to be merged.
STREAM_TASKS_IN_FLIGHT = HELD_TASKS + 1
# A worker's request for its next task, sent once its wavefront has taken every
# sample of the tasks it holds (see _Stream.next_job).
MORE = "more"
# A finished task's pixel sums held by the parent until merged: at worst one
# sample per pixel, so as many float64 RGB sums as samples.
RESULT_BYTES_PER_SAMPLE = 3 * 8
# A streaming worker keeps its held tasks' per-sample radiance (float64 RGB) in
# a buffer of 2 HELD_TASKS tasks (path.HeldTasks), against the one task
# BYTES_PER_PATH counts.
STREAM_BYTES_PER_PATH = (2 * HELD_TASKS - 1) * TASK_WAVEFRONTS * 3 * 8


@dataclass
class RenderStats:
    seed: int = 0
    elapsed: float = 0.0  # seconds: compiling, planning, rendering, forming the film
    samples: int = 0
    segments: int = 0
    shadow_rays: int = 0  # next-event estimation's shadow rays (path integrator)
    dropped: int = 0  # non-finite samples left out of their pixel
    units_done: int = 0
    units_total: int = 0
    workers: int = 1
    capacity: int = 0
    # Bytes: peak resident memory of the whole process tree, an upper bound
    # (the parent's peak plus every worker's); callers that go on to write
    # the image raise it to the parent's peak while writing.
    peak_memory: int = 0
    memory_estimate: int = 0  # what the plan expected the peak to be
    pixels_without_samples: int = 0
    checkpoint_error: str | None = None  # a checkpoint that could not be written

    @property
    def partial(self) -> bool:
        return self.units_done < self.units_total


@dataclass
class RenderResult:
    film: Film
    stats: RenderStats = field(default_factory=RenderStats)

    @cached_property
    def image(self) -> np.ndarray:
        """(H, W, 3) float32, linear, row 0 at the top."""
        return self.film.image()


# What compiling a scene takes, measured with ``benchmarks/bench.py --section
# budget`` (200,000 and 1,000,000 spheres): compile's (arrays, BVH) per
# primitive (the loader's per byte of YAML, LOAD_BYTES_PER_FILE_BYTE, is in
# memory.py).  They let a render that cannot fit be refused before the scene
# is read, not after it has already overrun the budget.
COMPILE_BYTES_PER_PRIMITIVE = 1024
# A medium's boundary primitive costs more: the boundary gets its own
# triangle set and BVH, its volume and the camera's winding number are
# computed over it, and it is compared with the visible primitives.  Measured
# on a 1.3M-face mesh boundary: 1.45 KiB each at compile's peak.
BOUNDARY_COMPILE_BYTES_PER_PRIMITIVE = 1536


def primitive_count(scene: Scene) -> int:
    """Primitives the acceleration structure will hold."""
    return len(scene.spheres) + len(scene.quads) + len(scene.triangles) + sum(len(m) for m in scene.meshes)


def boundary_primitive_count(scene: Scene) -> int:
    """Primitives of the media's boundaries (a sphere 1, a box 6, a mesh its faces)."""
    from .shapes import Box, Mesh

    return sum(len(m.boundary) if isinstance(m.boundary, Mesh) else 6 if isinstance(m.boundary, Box) else 1
               for m in scene.media)


def compile_bytes(scene: Scene) -> tuple[int, str]:
    """Compile's estimated peak and what it is for (the refusal's wording)."""
    visible, boundary = primitive_count(scene), boundary_primitive_count(scene)
    what = f"compiling {visible:,} primitives" + (f" and {boundary:,} medium-boundary primitives" if boundary else "")
    return COMPILE_BYTES_PER_PRIMITIVE * visible + BOUNDARY_COMPILE_BYTES_PER_PRIMITIVE * boundary, what


@dataclass(frozen=True)
class MemoryPlan:
    """How the render fits its budget; all sizes in bytes."""

    workers: int
    capacity: int
    base: int  # the parent as measured: interpreter, modules, scene, acceleration structure
    film: int  # film pages the render will still touch
    per_worker: int  # a worker at rest: the parent's pages it inherits
    output: int  # writing the image, after the workers have ended
    # The workers are processes that outlive the render (a local Dask cluster): even one is
    # not the parent, and they are still resident, wavefront and all, while the image is written.
    lasting: bool = False
    # The workers (or the parent, inline) stream tasks through one wavefront (path.hand_over):
    # the path integrator does, in this process or a pool; Whitted and Dask run a task at a time.
    streaming: bool = False

    @property
    def path_bytes(self) -> int:
        """A path in flight, with its share of the held tasks' radiance."""
        return BYTES_PER_PATH + (STREAM_BYTES_PER_PATH if self.streaming else 0)

    @property
    def result_bytes_per_path(self) -> int:
        """Finished tasks' sums out per worker, per path of its wavefront."""
        window = STREAM_TASKS_IN_FLIGHT if self.streaming else TASKS_IN_FLIGHT
        return window * TASK_WAVEFRONTS * RESULT_BYTES_PER_SAMPLE

    @property
    def render_peak(self) -> int:
        paths = self.capacity * self.path_bytes
        if self.workers == 1 and not self.lasting:  # inline: the parent renders
            return self.base + self.film + paths
        results = self.workers * self.capacity * self.result_bytes_per_path
        return self.base + self.film + results + self.workers * (self.per_worker + paths)

    @property
    def peak(self) -> int:
        writing = self.base + self.film + self.output
        if self.lasting:
            writing += self.workers * (self.per_worker + self.capacity * self.path_bytes)
        return max(self.render_peak, writing)


def plan_memory(memory: int, workers: int, chunk_size: int | None, *, base: int, film: int,
                per_worker: int, output: int, lasting: bool = False, streaming: bool = False,
                cluster: int = 0) -> MemoryPlan:
    """Workers and wavefront size that fit ``memory`` bytes, the most workers first.

    An explicit ``chunk_size`` is kept (fewer workers are used if need be);
    otherwise the wavefront is as large as fits, up to ``MAX_CAPACITY``, and
    a worker is dropped rather than run one below ``GOOD_CAPACITY``.  With
    ``lasting`` (worker processes already running, that outlive the render:
    see :class:`MemoryPlan`) only ``workers`` is planned for; ``streaming``
    as in :class:`MemoryPlan`.  ``cluster``: bytes a Dask cluster takes
    beside this process's ``base`` (planned as part of the base; named apart
    in the refusal, whose ``base`` is then what this process holds).

    Raises
    ------
    MemoryBudgetError
        When even one process at the smallest wavefront does not fit; the
        message gives the estimate.
    """
    held, base = base, base + cluster
    fallback = None
    for w in range(workers, workers - 1 if lasting else 0, -1):
        plan = MemoryPlan(w, chunk_size or MIN_CAPACITY, base, film, per_worker, output, lasting, streaming)
        if chunk_size is None:
            spare = memory - plan.peak
            per_path = w * plan.path_bytes + (w * plan.result_bytes_per_path if w > 1 or lasting else 0)
            capacity = min(MAX_CAPACITY, MIN_CAPACITY + max(0, spare) // per_path)
            plan = MemoryPlan(w, capacity, base, film, per_worker, output, lasting, streaming)
            # growing the wavefront raises only render_peak; shrink if the estimate rounds over
            while plan.peak > memory and plan.capacity > MIN_CAPACITY:
                plan = MemoryPlan(w, max(MIN_CAPACITY, plan.capacity * 7 // 8), base, film, per_worker, output,
                                  lasting, streaming)
        if plan.peak <= memory:
            if chunk_size is not None or plan.capacity >= GOOD_CAPACITY or w == 1:
                return plan
            fallback = fallback or plan
    if fallback is not None:
        return fallback
    smallest = MemoryPlan(workers if lasting else 1, chunk_size or MIN_CAPACITY, base, film, per_worker, output,
                          lasting, streaming)
    parts = [f"{_mib(held)} held by this process", f"Dask {_mib(cluster)}"] if cluster else \
        [f"the process and scene {_mib(base)}"]
    if lasting:
        parts.append(f"{smallest.workers} worker process{'es' if smallest.workers > 1 else ''} "
                     f"{_mib(smallest.workers * per_worker)}")
    if film:
        parts.append(f"the film {_mib(film)}")
    # the parts of whichever peak is the larger, so that they add up to it: the render's
    # (paths in flight, and where workers send results, their finished tasks' sums) or
    # writing the image's (with lasting workers still resident, their paths too)
    paths = f"{smallest.capacity} paths in flight {_mib(smallest.capacity * smallest.path_bytes)}"
    if smallest.peak > smallest.render_peak:
        parts += [paths, f"writing the image {_mib(output)}"] if lasting else [f"writing the image {_mib(output)}"]
    else:
        parts.append(paths)
        if smallest.workers > 1 or lasting:
            results = smallest.workers * smallest.capacity * smallest.result_bytes_per_path
            parts.append(f"finished tasks' results {_mib(results)}")
    total, budget = over_budget(smallest.peak, memory)
    raise MemoryBudgetError(f"the render needs about {total} ({', '.join(parts)}), "
                            f"more than the memory budget of {budget}")


def plan_local_workers(scene: Scene, memory: int, workers: int, chunk_size: int | None, *, held: int,
                       cluster: int, worker_bytes: int, film: int, output: int) -> MemoryPlan:
    """The plan for ``workers`` worker processes on this machine that outlive
    the render (a Dask LocalCluster; see :class:`MemoryPlan`'s ``lasting``):
    each ``worker_bytes`` at rest plus the scene it compiles, beside this
    process (``held`` bytes) and the ``cluster``'s own bytes.  The command
    makes it before it starts the cluster too, with Dask's share estimated,
    so a render that cannot fit is refused before the cluster's processes
    exist (:func:`wavefront.distributed.refuse_unless_local_render_fits`).

    Raises
    ------
    MemoryBudgetError
        As :func:`plan_memory`.
    """
    return plan_memory(memory, workers, chunk_size, base=held, cluster=cluster, film=film,
                       per_worker=worker_bytes + compile_bytes(scene)[0], output=output, lasting=True)


def _mib(size: int) -> str:
    return f"{size / MiB:,.1f} MiB" if size < 10 * MiB else f"{size / MiB:,.0f} MiB"


# --- tasks ---------------------------------------------------------------------

def plan_tasks(plan: UnitPlan, capacity: int, workers: int = 1, first_unit: int = 0):
    """Consecutive units grouped into tasks that shrink towards the end; lazy.

    Guided scheduling: each task takes about 1/(2 * workers) of the samples
    still unplanned (at most TASK_WAVEFRONTS wavefronts, at least one), so
    the first tasks are long and keep every wavefront full, and the last are
    short so no worker finishes long before the others.  Tiles differ in cost
    (sky is cheap), and with four equal tasks one worker of W2 idled for up
    to a fifth of the wall time.  A task holds at least one full wavefront,
    unless the whole render is smaller than a wavefront per worker: then it
    is shared out evenly, so a small image (a preview, a few samples of a
    128x128 box) still runs on every worker instead of one task in one
    process, down to ``SMALLEST_SHARED_TASK`` samples a task.  When every
    worker's share fits in one task (TASK_WAVEFRONTS wavefronts), each worker
    gets exactly one: a task ended in a tail of a few deep paths costing
    ~0.5 ms a bounce however few they are (~20 ms on cornell_spheres), and
    two tasks a worker were ~5 % slower than one at 128x128, 16 spp
    (interleaved runs; measured before workers streamed one task into the
    next, path.hand_over, which leaves only the last task's tail).  Grouping
    never changes the image: units are merged in order.  Yields lists of
    units.
    """
    remaining = plan.total_samples - plan.samples_before(first_unit)
    share = -(-remaining // workers)
    smallest = min(capacity, max(SMALLEST_SHARED_TASK, share))
    if share <= TASK_WAVEFRONTS * capacity:
        yield from _even_tasks(plan, first_unit, remaining, -(-remaining // max(smallest, share)))
        return
    current, size, target = [], 0, 0
    for i in range(first_unit, len(plan)):
        unit = plan[i]
        if not current:
            target = min(TASK_WAVEFRONTS * capacity, max(smallest, remaining // (2 * workers)))
        current.append(unit)
        size += unit.size
        if size >= target:
            yield current
            remaining -= size
            current, size = [], 0
    if current:
        yield current


def _even_tasks(plan: UnitPlan, first_unit: int, remaining: int, count: int):
    """The units from ``first_unit`` (``remaining`` samples) in ``count``
    tasks (fewer only if units are too coarse) as near equal as whole units
    allow.  Units differ in size (sample passes double: 1, 1, 2, 4, ... spp),
    so each task aims at an equal part of what is left, and closes before a
    unit that would overshoot that more than the task falls short of it
    (closing only past it made the first task swallow nearly everything when
    resuming, or with three workers)."""
    current, size, target = [], 0, 0
    for i in range(first_unit, len(plan)):
        unit = plan[i]
        if not current:
            target = -(-remaining // count)
        elif count > 1 and size + unit.size - target > target - size:
            yield current
            remaining, count = remaining - size, count - 1
            current, size, target = [], 0, -(-remaining // count)
        current.append(unit)
        size += unit.size
        if count > 1 and size >= target:
            yield current
            remaining, count = remaining - size, count - 1
            current, size = [], 0
    if current:
        yield current


def tune_allocator() -> None:
    """Keep freed wavefront temporaries in the heap instead of unmapping them.

    glibc serves every allocation above its mmap threshold (128 KiB at
    first) with a fresh ``mmap`` and returns it with ``munmap``, so a 64 Ki
    path wavefront faulted in every temporary again on every bounce: a fifth
    of the render time went to the kernel (``benchmarks/bench.py --section capacity``).
    Raising the thresholds makes the heap reuse those pages; the peak
    resident memory is unchanged.  No-op where glibc is absent.
    """
    lib = libc()
    if lib is None:
        return
    m_trim_threshold, m_mmap_threshold = -1, -3
    lib.mallopt(m_mmap_threshold, 32 * MiB)  # glibc's maximum on 64-bit
    lib.mallopt(m_trim_threshold, 256 * MiB)


# --- work done in a worker (or inline) --------------------------------------

@dataclass
class _Worker:
    """What a process needs to run tasks: set once per process."""

    compiled: CompiledScene
    key: object
    capacity: int
    should_stop: object = None


_WORKER: list[_Worker] = []  # at most one: this process's


def _die_with_parent(parent: int) -> None:
    """End this worker when the parent dies, even by SIGKILL.

    Linux's ``PR_SET_PDEATHSIG`` sends the signal when the parent exits;
    elsewhere a watchdog thread polls the parent id.  Either way no orphan
    keeps computing and printing broken-pipe tracebacks.
    """
    lib = libc()
    pr_set_pdeathsig = 1
    if lib is None or lib.prctl(pr_set_pdeathsig, signal.SIGKILL, 0, 0, 0) != 0:
        def watch():
            while os.getppid() == parent:
                time.sleep(0.2)
            os._exit(1)

        threading.Thread(target=watch, daemon=True).start()
    if os.getppid() != parent:  # the parent died before the line above
        os._exit(1)


def _init_worker(scene: Scene, capacity: int, parent: int, compiled: CompiledScene | None = None,
                 key=None) -> None:
    _die_with_parent(parent)
    # The parent decides what an interrupt means; workers just get killed.
    # A forked worker inherits the parent's Python handlers: a SIGTERM (say,
    # to the whole process group) must end it, not set the parent's flag.
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    tune_allocator()
    reserve_heap(capacity * BYTES_PER_PATH)
    compiled = compiled if compiled is not None else scene.compile()
    key = key if key is not None else scene_key(scene.render.seed)
    _WORKER[:] = [_Worker(compiled, key, capacity)]


def execute(cs: CompiledScene, key, capacity: int, units: list[Unit], should_stop=None):
    """Render the units of one task: the same work wherever it runs.

    Returns per-unit results, trace counters and ``(pid, peak RSS)``.
    """
    scene = cs.scene
    job = Job(units, scene.width, scene.render.samples_per_pixel)
    stats = TraceStats()
    # Overflow and NaN are handled by the film (non-finite samples are dropped
    # and counted in the summary), so NumPy's warnings about them are noise.
    with np.errstate(over="ignore", invalid="ignore"):
        radiance = TRACERS[scene.render.integrator](cs, job, key, capacity, stats, should_stop)
    if should_stop is not None and should_stop():
        raise RenderInterrupted  # the trace was cut short: this task's samples are incomplete
    return job.reduce(radiance), stats, (os.getpid(), peak_rss())


def run_task(units: list[Unit]):
    """:func:`execute` with the scene this process was initialised with."""
    w = _WORKER[0]
    return execute(w.compiled, w.key, w.capacity, units, w.should_stop)


class _Stream(TaskStream):
    """Tasks from ``receive`` (units, or None when none is waiting), results
    as :func:`execute` makes them to ``deliver``.  ``ask``, if given, is
    called once each time the wavefront wants a task while its last paths
    run and none is waiting (an idle trace ends, and its worker waits)."""

    def __init__(self, scene: Scene, receive, deliver, ask=None):
        self.scene, self.receive, self.deliver, self.ask = scene, receive, deliver, ask
        self.asked = False

    def job(self, units: list[Unit]) -> Job:
        return Job(units, self.scene.width, self.scene.render.samples_per_pixel)

    def next_job(self, idle: bool) -> Job | None:
        units = self.receive()
        if units is None:
            if self.ask is not None and not self.asked and not idle:
                self.ask()
                self.asked = True
            return None
        self.asked = False
        return self.job(units)

    def finished(self, job: Job, stats: TraceStats, radiance: np.ndarray) -> None:
        self.deliver((job.reduce(radiance), stats, (os.getpid(), peak_rss())))


def run_stream(units: list[Unit], receive, deliver, ask=None) -> None:
    """Render task ``units`` and the tasks ``receive()`` gives while it runs,
    in one wavefront (``receive`` returns None when no task is waiting: the
    trace ends once its wavefront is empty), handing each task's result, as
    :func:`run_task` returns it, to ``deliver``, in order; ``ask()`` (if
    given) is called when the wavefront wants a task and none is waiting.
    An integrator that does not stream runs ``units`` alone."""
    w = _WORKER[0]
    scene = w.compiled.scene
    if scene.render.integrator not in STREAMING:
        deliver(run_task(units))
        return
    stream = _Stream(scene, receive, deliver, ask)
    with np.errstate(over="ignore", invalid="ignore"):  # as in execute
        TRACERS[scene.render.integrator](w.compiled, stream.job(units), w.key, w.capacity, None, w.should_stop,
                                         stream=stream)
    if w.should_stop is not None and w.should_stop():
        raise RenderInterrupted  # the tasks not yet delivered are incomplete


MAX_WORKERS = 1024  # far past any machine's cores; bounds the planning too


def _check_arguments(*, memory, workers, chunk_size, checkpoint_interval, progress, should_stop, executor):
    """The arguments of :func:`render_scene`, by the command line's rules; ValueError or TypeError."""
    check_budget(memory)
    for name, value, high in (("workers", workers, MAX_WORKERS), ("chunk_size", chunk_size, 1 << 31)):
        if value is not None and (isinstance(value, bool) or not isinstance(value, int) or not 1 <= value <= high):
            raise ValueError(f"{name}: expected an integer in [1, {high:,}] or None, got {value!r}")
    if isinstance(checkpoint_interval, bool) or not isinstance(checkpoint_interval, (int, float)) \
            or not 0 < checkpoint_interval < float("inf"):
        raise ValueError(f"checkpoint_interval: expected a positive number of seconds, got {checkpoint_interval!r}")
    for name, value in (("progress", progress), ("should_stop", should_stop), ("executor", executor)):
        if value is not None and not callable(value):
            raise TypeError(f"{name}: expected a callable or None, got {value!r}")


def compile_within(scene: Scene, memory: int) -> CompiledScene:
    """``scene.compile()``, refused first if its estimate does not fit in ``memory``."""
    refuse_unless_fits(memory, *compile_bytes(scene))
    return scene.compile()


def render(scene: Scene, **options) -> np.ndarray:
    """Render ``scene``; returns the linear float32 image of shape (H, W, 3).

    Keyword arguments are those of :func:`render_scene`.
    """
    return render_scene(scene, **options).image


class RenderInterrupted(Exception):
    """Raised inside a task when the render was asked to stop."""


class RenderError(RuntimeError):
    """The render could not finish: its worker processes kept dying."""


def render_scene(scene: Scene, *, workers: int | None = None, memory: int = DEFAULT_MEMORY,
                 chunk_size: int | None = None, progress=None, should_stop=None,
                 checkpoint: str | None = None, checkpoint_interval: float = 30.0,
                 resume: str | None = None, executor=None, output_bytes: int | None = None,
                 compiled: CompiledScene | None = None) -> RenderResult:
    """Render with full control and statistics.

    Parameters
    ----------
    scene : Scene
    workers : int, optional
        Processes to use; default all cores, fewer if the memory budget needs
        it.  The image does not depend on it.
    memory : int
        Memory budget in bytes for the whole process tree (scene, acceleration
        structure, film, every worker, and ``output_bytes`` for writing the
        image); sets the wavefront size and, if need be, the worker count.
    chunk_size : int, optional
        Paths in flight per worker, instead of as many as the budget allows
        (tests use it to show the image does not depend on it).
    progress : callable(samples_done: int, samples_total: int), optional
    should_stop : callable() -> bool, optional
        Polled several times a second; when it returns True the render stops
        and returns the samples finished so far (``stats.partial``).
    checkpoint : str, optional
        File (``.npz``) to save progress to every ``checkpoint_interval``
        seconds and when the render ends or stops.  Checked before
        rendering; a save that fails later is reported in
        ``stats.checkpoint_error`` (with a warning) and never loses the image.
    resume : str, optional
        A checkpoint of the same scene and settings to continue from; the
        result is identical to an uninterrupted render.
    executor : callable, optional
        ``executor(scene, capacity, tasks, merge, stopped)`` runs the tasks
        (an iterable) somewhere else (see :mod:`wavefront.distributed`) and
        calls ``merge`` with each task's result in task order.  Default:
        inline for one worker, a local process pool for more.
    output_bytes : int, optional
        Memory needed after the render to use the image (default: the
        float32 image the API returns).
    compiled : CompiledScene, optional
        ``scene`` already compiled (the CLI compiles it while checking it).

    Raises
    ------
    CheckpointError
        If ``resume`` is not a checkpoint of this render.
    MemoryBudgetError
        If the render cannot fit in ``memory``.
    OutputError
        If ``checkpoint`` cannot be written.
    """
    start = time.perf_counter()
    if not isinstance(scene, Scene):
        raise TypeError(f"scene: expected a Scene (wavefront.load_scene reads a file), got {type(scene).__name__}")
    _check_arguments(memory=memory, workers=workers, chunk_size=chunk_size, checkpoint_interval=checkpoint_interval,
                     progress=progress, should_stop=should_stop, executor=executor)
    tune_allocator()
    if checkpoint is not None:
        if not str(checkpoint).endswith(".npz"):
            raise OutputError(f"{checkpoint}: a checkpoint file name must end in .npz")
        check_output_path(checkpoint, image=False)
    pixels = scene.width * scene.height
    plan = UnitPlan(scene.width, scene.height, scene.render.samples_per_pixel)
    if resume is not None:
        refuse_unless_fits(memory, pixels * FILM_BYTES_PER_PIXEL, f"resuming a {scene.width}x{scene.height} film")
        film, first_unit = load_checkpoint(resume, scene, len(plan))
    else:
        film, first_unit = Film(scene.width, scene.height), 0
    cs = compiled if compiled is not None or executor is not None else compile_within(scene, memory)
    requested = max(1, workers if workers is not None else (os.cpu_count() or 1))
    release_free_memory()
    base = current_rss()
    load_peak = phase_peak()  # loading and compiling; from here on the parent's peak is the render's
    # An executor's workers on this machine (a Dask LocalCluster: ``local_workers``
    # processes of ``worker_bytes`` at rest, plus ``cluster_bytes`` beside them) are in
    # this process tree and inside the budget: each holds the scene, compiled, and a
    # wavefront.  A remote cluster's memory is its own: the parent plans for itself.
    local = getattr(executor, "local_workers", 0) if executor is not None else 0
    film_bytes = 0 if resume is not None else pixels * FILM_BYTES_PER_PIXEL
    output = pixels * 3 * 4 if output_bytes is None else output_bytes
    if local:
        budget = plan_local_workers(scene, memory, local, chunk_size, held=base, cluster=executor.cluster_bytes,
                                    worker_bytes=executor.worker_bytes, film=film_bytes, output=output)
    else:
        budget = plan_memory(memory, 1 if executor is not None else requested, chunk_size, base=base,
                             film=film_bytes, per_worker=base, output=output,
                             streaming=executor is None and scene.render.integrator in STREAMING)
    capacity = budget.capacity
    workers = requested if executor is not None else budget.workers
    # Units are merged strictly in order, so "the first k units" describes
    # any partial state exactly; resuming merges the rest in the same order.
    tasks = plan_tasks(plan, capacity, workers, first_unit)
    if executor is None and workers > 1:  # no more processes than tasks
        first = list(itertools.islice(tasks, workers))
        workers = max(1, len(first))
        tasks = itertools.chain(first, tasks)
    stats = RenderStats(seed=scene.render.seed, units_done=first_unit, units_total=len(plan),
                        workers=workers, capacity=capacity, memory_estimate=budget.peak)
    total_samples = plan.total_samples
    done_samples = plan.samples_before(first_unit)
    worker_peaks: dict[int, int] = {}
    last_save = time.monotonic()

    def save() -> None:
        if stats.checkpoint_error is not None:
            return
        try:
            save_checkpoint(checkpoint, scene, film, stats.units_done)
        except OutputError as e:
            stats.checkpoint_error = f"cannot write the checkpoint: {e}"
        except OSError as e:
            stats.checkpoint_error = f"{checkpoint}: cannot write the checkpoint: {e.strerror or e}"
        if stats.checkpoint_error is not None:
            warnings.warn(stats.checkpoint_error, RuntimeWarning, stacklevel=3)

    def merge(result) -> None:
        nonlocal last_save, done_samples
        unit_results, trace_stats, peak = result
        for unit, total, count, dropped in unit_results:
            film.add(unit, total, count)
            film.dropped += dropped
            stats.dropped += dropped
            stats.units_done += 1
            done_samples += unit.size
        stats.samples += trace_stats.samples
        stats.segments += trace_stats.segments
        stats.shadow_rays += trace_stats.shadow_rays
        pid, rss = peak
        worker_peaks[pid] = max(worker_peaks.get(pid, 0), rss)
        if progress is not None:
            progress(done_samples, total_samples)
        if checkpoint is not None and time.monotonic() - last_save >= checkpoint_interval:
            save()
            last_save = time.monotonic()

    stopped = lambda: should_stop is not None and bool(should_stop())  # noqa: E731
    try:
        if executor is not None:
            executor(scene, capacity, tasks, merge, stopped)
        elif workers == 1:
            _run_inline(cs, capacity, tasks, merge, stopped)
        else:
            _run_pool(scene, cs, capacity, tasks, merge, stopped, workers)
    except RenderInterrupted:
        pass
    except RenderError:
        if checkpoint is not None:
            save()  # what was finished can still be resumed
        raise
    if checkpoint is not None:
        save()
    worker_peaks.pop(os.getpid(), None)  # inline tasks ran in this process
    # a local cluster's workers report their peaks with their results; beside them, its tracker
    stats.peak_memory = max(load_peak, phase_peak(reset=False) + sum(worker_peaks.values())
                            + (executor.cluster_bytes if local else 0))
    stats.pixels_without_samples = film.pixels_without_samples
    release_free_memory()  # the wavefront's temporaries, before the image is written
    stats.elapsed = time.perf_counter() - start
    return RenderResult(film, stats)


POLL_SECONDS = 0.1  # how often a waiting parent checks for a stop request
MAX_WORKER_DEATHS = 3  # past this, a render whose workers keep dying (out of memory?) gives up
ENDING_SECONDS = 5.0  # the most a finished render's workers are given to exit before they are killed


def _exit_cause(code: int) -> str:
    if code < 0:
        try:
            return f"killed by {signal.Signals(-code).name}"
        except ValueError:
            return f"killed by signal {-code}"
    return f"exit status {code}"


def _run_inline(cs, capacity, tasks, merge, stopped) -> None:
    saved = list(_WORKER)
    _WORKER[:] = [_Worker(cs, scene_key(cs.scene.render.seed), capacity, stopped)]
    tasks = iter(tasks)
    try:
        for task in tasks:
            if stopped():
                raise RenderInterrupted
            run_stream(task, lambda: next(tasks, None), merge)
    finally:
        _WORKER[:] = saved


class _Inbox:
    """A worker's end of its pipe: the tasks the parent sends, each as
    ``((first unit, units), last)`` (see :func:`_task_message`), until None
    or a task sent as the last; and its requests for more."""

    def __init__(self, conn, plan: UnitPlan):
        self.conn, self.plan, self.ended = conn, plan, False

    def task(self, wait: bool = True) -> list[Unit] | None:
        """The next task's units; None once the parent has ended the
        stream, or (``wait=False``) when no task is waiting yet."""
        if self.ended or (not wait and not self.conn.poll()):
            return None
        message = self.conn.recv()
        if message is None:
            self.ended = True
            return None
        (first, count), self.ended = message
        return [self.plan[i] for i in range(first, first + count)]

    def ask(self) -> None:
        """Ask the parent for the next task (unless it has said there is none)."""
        if not self.ended:
            self.conn.send((MORE, None))


def _task_message(units: list[Unit]) -> tuple[int, int]:
    """A task as the parent sends it: its first unit's index and its number of
    units (a task is a run of consecutive units).  A few bytes, so the
    parent's send never blocks: a list of units took ~47 bytes each (a
    1-pixel-wide image at 1 spp has ~4,000 units a task), and a parent
    blocked sending a task to a worker that was itself blocked sending a
    result to it hung the render."""
    return units[0].index, len(units)


def _serve(conn, scene, capacity, parent, compiled, key) -> None:
    """A worker process: run the tasks the parent sends, send back each result.

    Once the wavefront has taken every sample of its task the worker asks for
    the next (``MORE``), and runs on into it while the last paths of the
    first are still in flight (:func:`run_stream`); each result goes back as
    soon as its task's paths have ended.  An error is sent back too,
    with its traceback, and raised in the parent.  None from the parent ends
    the worker, and so does a task sent as its last (the render's last, or
    any after which the plan is empty): the worker exits once its results
    are sent, while the parent merges them.
    """
    _init_worker(scene, capacity, parent, compiled, key)
    inbox = _Inbox(conn, plan_units(scene.width, scene.height, scene.render.samples_per_pixel))
    while (task := inbox.task()) is not None:
        try:
            run_stream(task, lambda: inbox.task(wait=False), lambda result: conn.send((True, result)), inbox.ask)
        except Exception as e:  # noqa: BLE001 (any error of a task, or a result that does not pickle)
            where = traceback_of(e)
            try:
                conn.send((False, (e, where)))
            except Exception:  # noqa: BLE001 (an error that does not pickle)
                conn.send((False, (RuntimeError(f"{type(e).__name__}: {first_line(e)}"), where)))


def traceback_of(error: BaseException) -> str:
    import traceback  # only when a task failed

    return "".join(traceback.format_exception(error))


class WorkerTraceback(Exception):
    """Where a task failed in its worker process: the ``__cause__`` of the error re-raised in the parent."""

    def __str__(self) -> str:
        return f"in the worker process:\n{self.args[0]}"


@dataclass
class _WorkerProcess:
    """One worker as the parent sees it."""

    process: object  # multiprocessing.Process
    conn: object  # the parent's end of its pipe
    tasks: list[int] = field(default_factory=list)  # the numbers of the tasks given it and not done, in order
    wants: bool = False  # it asked for another task (MORE) and has not been given one since
    # Told it has no more work (None, or its task sent as the last): it exits
    # by itself, and its exit is not a death.
    retired: bool = False


class _Workers:
    """Worker processes, each with a pipe of its own: the parent sends tasks
    (one when a worker is idle, another when it asks) and reads back their results.

    In place of ``multiprocessing.Pool``, whose start (three handler threads),
    result path and end cost ~10 ms of a 0.1 s render, and which needed its
    private state to notice a dead worker or to end a pool whose dead worker
    took a shared queue's lock with it.  Here nothing is shared: a worker
    that dies (killed, out of memory) is seen on its process sentinel, its
    tasks go back to the plan's front and a new worker takes its place.
    """

    def __init__(self, ctx, count: int, initargs: tuple):
        self.ctx, self.initargs, self.exit_codes, self.all = ctx, initargs, [], []
        try:
            for _ in range(count):
                self.all.append(self._start())
        except BaseException:  # a fork that failed, an interrupt: no worker is left behind
            self.kill()
            raise

    def _start(self) -> _WorkerProcess:
        ours, theirs = self.ctx.Pipe()
        process = self.ctx.Process(target=_serve, args=(theirs, *self.initargs), daemon=True,
                                   name="wavefront worker")
        process.start()
        theirs.close()
        return _WorkerProcess(process, ours)

    @staticmethod
    def retire(worker: _WorkerProcess) -> None:
        """Tell an idle worker to exit."""
        worker.retired = True
        try:
            worker.conn.send(None)
        except OSError:
            pass  # it died meanwhile

    def bury(self, worker: _WorkerProcess, replace: bool) -> None:
        """Note a dead worker's exit; start another in its place if there is work left."""
        worker.conn.close()
        worker.process.join()
        self.exit_codes.append(worker.process.exitcode)
        if len(self.exit_codes) > MAX_WORKER_DEATHS:
            causes = ", ".join(sorted({_exit_cause(code) for code in self.exit_codes}))
            raise RenderError(f"{len(self.exit_codes)} worker processes died ({causes}); "
                              "if the system ran out of memory, lower --memory or --workers")
        i = self.all.index(worker)
        if replace:
            self.all[i] = self._start()
        else:
            del self.all[i]

    def reap(self, worker: _WorkerProcess) -> None:
        """Join a retired worker that has exited, and forget it."""
        worker.conn.close()
        worker.process.join()
        self.all.remove(worker)

    def kill(self) -> None:
        """End every worker now, whatever it is doing."""
        for worker in self.all:
            worker.process.kill()
        for worker in self.all:
            worker.conn.close()
            worker.process.join()

    def end(self) -> None:
        """End every worker (all idle: the render has finished), all at once."""
        for worker in self.all:
            # None, not just closing the pipe: workers forked later hold
            # copies of this end, so the worker would never see it close
            if not worker.retired:
                self.retire(worker)
            worker.conn.close()
        deadline = time.monotonic() + ENDING_SECONDS
        for worker in self.all:
            worker.process.join(max(0.0, deadline - time.monotonic()))
            if worker.process.exitcode is None:
                worker.process.kill()
                worker.process.join()


# What a pool costs beyond its tasks (W1, 2 workers, session 10): on an idle
# machine the process tree's CPU time was that of the inline render (3.25 s
# against 3.30), the parent's ~0.21 s included: imports ~0.12, loading,
# compiling and forking ~0.015, reading and merging results ~0.06 (film.add
# 0.011-0.024 of it) while the workers run, writing the PNG ~0.05 after them.
# Workers get their first task within 0.3 ms of starting and end within ~10 ms
# of each other.  Tried and not kept: a 2 MiB socket send buffer, so a worker
# never blocks handing over a result (~50 ms a worker on W1, mostly reducing
# and pickling it, unchanged; tried again in session 12: the parent's reading
# 22-70 ms of CPU with it against 22-49 without, on a loaded machine).
# Session 12, W1 timed as the benchmark does (render_scene in a fresh process,
# elapsed 1.59-1.68 s in 5 runs at load ~2): the parent forks the first worker
# 4-6 ms after the start (compiling 0.9 ms; importing multiprocessing ~3 ms,
# which a warm-up render, run inline, never does) and the second 1.5-4 ms
# later; a worker's first bounce (its first 65,536 camera rays, first touches)
# takes 10-55 ms of CPU.  While they run the parent uses 48-58 ms of CPU
# (reading 38 results of ~0.8 MB, the first 6.6 MB, and 37 requests 20-25,
# film.add 11-12, waiting 7-12); a worker hands over a task in ~1.4 ms of CPU
# (reducing ~1.2, pickling ~0.25), the first task's 23-40 ms in 10 runs of 15,
# and collects garbage once a render.  At the end each worker
# drains 22-31 bounces (11-22 ms; the last ~15 of one or two paths), they exit
# 2-15 ms apart, and the last exit is 5-7 ms before the return (joining the
# workers 2-6 ms, malloc_trim 1.1).  Cores idle or used by the parent: 2 x
# elapsed - the workers' CPU = 95-135 ms of ~3.3 s, so at most ~4 % of the
# elapsed time is not a worker rendering: the rest of W1 is per-segment work.
# Tried and not kept: closing a task once its units cover 65,536 pixels, so
# the first task (67 units of the 1-spp passes, a 6.6 MB result against the
# later tasks' 0.8 MB; ~13 MB of fresh memory reduced and pickled, 23-40 ms of
# mostly kernel CPU in 10 runs of 15, 7-10 ms in the others) went out as
# one-wavefront tasks of 1.5 MB (first hand-over 2.5-5.6 ms): both workers'
# hand-overs over the render 75 ms against 80 (means of 8 interleaved runs,
# medians 76 and 77; 40 tasks instead of 38), W1's CPU 0.989 of the tree
# without it (median of 9, per-run 0.92-1.13): not measurable.
def _run_pool(scene, cs, capacity, tasks, merge, stopped, workers) -> None:
    import multiprocessing  # here: a render of one task (or one worker) runs inline and never needs it
    from multiprocessing.connection import wait

    fork = "fork" in multiprocessing.get_all_start_methods()
    ctx = multiprocessing.get_context("fork" if fork else "spawn")
    # Forked workers inherit the scene compiled and the key derived here:
    # doing both in each of them (first imports of the BVH and of
    # numpy.random included) held back the first tasks by ~40 ms, 8 % of W2.
    compiled, key = (cs, scene_key(scene.render.seed)) if fork else (None, None)
    pool = _Workers(ctx, workers, (scene, capacity, os.getpid(), compiled, key))
    try:
        # Tasks are numbered and merged strictly in that order; at most a
        # window of them is out (held by a worker, or finished and waiting for
        # an earlier one), so the plan is never materialised and what waits to
        # be merged is bounded, however many samples the render has.  An idle
        # worker is given a task at once; a busy one when it asks (MORE), up to
        # HELD_TASKS, or as soon as the window allows if it asked when it was full.
        # A dead worker's tasks are run again, before any new one (lowest
        # first): a result depends on its task alone, so the image is unchanged.
        # Workers with nothing left to do are retired at once, so their exits
        # (~2 ms each: tearing down a forked address space) overlap the
        # render's last tasks and merges instead of following them; a task
        # given out when the plan is empty is sent as its worker's last.
        plan = enumerate(tasks)
        upcoming = next(plan, None)  # the plan's next (number, task); None once all are given out
        window = STREAM_TASKS_IN_FLIGHT * workers
        lost = []  # (number, task) of dead workers
        task_of, finished = {}, {}  # number -> task given out; number -> result not yet merged
        merged = issued = 0  # tasks merged; tasks taken from the plan

        def give(worker: _WorkerProcess) -> None:
            """Send ``worker`` a task if the window allows (or, idle with nothing left, its end)."""
            nonlocal issued, upcoming
            if lost:
                number, task = lost.pop(0)
            elif upcoming is None:
                if not worker.tasks:
                    pool.retire(worker)
                return
            elif issued - merged >= window:
                return
            else:
                (number, task), issued = upcoming, issued + 1
                upcoming = next(plan, None)
            task_of[number] = task
            worker.tasks.append(number)
            worker.wants = False
            worker.retired = upcoming is None and not lost
            try:
                worker.conn.send((_task_message(task), worker.retired))
            except OSError:
                pass  # it has just died: its sentinel says so, and its tasks go back to `lost`

        while True:
            for worker in pool.all:
                if not worker.retired and (not worker.tasks or worker.wants and len(worker.tasks) < HELD_TASKS):
                    give(worker)
            if not task_of:
                break
            busy = [w.conn for w in pool.all if w.tasks]
            ready = set(wait(busy + [w.process.sentinel for w in pool.all], POLL_SECONDS))
            if stopped():
                raise RenderInterrupted
            for worker in list(pool.all):
                exited = worker.process.sentinel in ready or not worker.process.is_alive()
                # Results come back in the order the tasks were given; every one
                # that has arrived is read.  A worker sent its last task sends its
                # results and exits, maybe after `ready` was taken: they are read
                # before it is judged (at a dead worker's end of file, poll is True too)
                while worker.tasks and (worker.conn in ready or exited) and worker.conn.poll():
                    try:
                        ok, value = worker.conn.recv()
                    except (EOFError, OSError):  # it died sending: its sentinel says so
                        break
                    if ok == MORE:
                        # Its wavefront has taken every sample it has: the next task now
                        # (or once the window allows), so it runs on into it instead of
                        # draining.  Not sooner: a task given is a task no other worker
                        # can take, and the plan's last, short tasks must go to whichever
                        # worker is free first.
                        worker.wants = True
                        if len(worker.tasks) < HELD_TASKS and not worker.retired:
                            give(worker)
                        continue
                    if not ok:
                        error, where = value
                        raise error from WorkerTraceback(where)  # the task's own error
                    number = worker.tasks.pop(0)
                    finished[number] = value
                    del task_of[number]
                    if not worker.tasks and not worker.retired:
                        give(worker)  # at once: it works while the parent merges
                if exited:
                    if worker.retired and not worker.tasks:
                        pool.reap(worker)  # it exited as told
                        continue
                    lost.extend((number, task_of[number]) for number in worker.tasks)
                    lost.sort(key=lambda item: item[0])
                    pool.bury(worker, replace=bool(lost) or upcoming is not None)
            while merged in finished:
                merge(finished.pop(merged))
                merged += 1
    except BaseException:
        pool.kill()
        raise
    pool.end()
