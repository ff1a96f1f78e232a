"""The render driver: units of work, the local process pool, the film.

The render is a fixed list of units (:mod:`wavefront.film`) grouped into
tasks of a few wavefronts' worth of samples.  Tasks run inline or on a process
pool; their results are merged in task order, so the image does not depend on
the worker count, and the chunk size (wavefront capacity) only decides how
many paths are in flight, never which random numbers a path sees.
"""

from __future__ import annotations

import contextlib
import hashlib
import multiprocessing
import os
import resource
import signal
import tempfile
import time
import zipfile
from dataclasses import dataclass, field

import numpy as np

from .film import Job, Unit, plan_units
from .output import publish
from .integrators import TRACERS
from .path import TraceStats
from .sampling import scene_key
from .scene import CompiledScene, Scene

MiB = 1024 * 1024
DEFAULT_MEMORY = 1024 * MiB  # whole render, all processes
# Measured bytes per path in flight, the batch and every per-bounce temporary
# included; see ``benchmarks/bench.py --section capacity``.
BYTES_PER_PATH = 1500
MAX_CAPACITY = 1 << 16  # larger wavefronts fall out of cache and get slower
MIN_CAPACITY = 256
BASE_PROCESS_BYTES = 80 * MiB  # interpreter + NumPy + scene in each worker
TASK_WAVEFRONTS = 4  # a task holds about this many wavefronts' samples
FLOAT32_MAX = float(np.finfo(np.float32).max)


@dataclass
class RenderStats:
    seed: int = 0
    elapsed: float = 0.0
    samples: int = 0
    segments: int = 0
    dropped: int = 0  # non-finite samples left out of their pixel
    units_done: int = 0
    units_total: int = 0
    workers: int = 1
    capacity: int = 0
    peak_memory: int = 0  # bytes: parent's peak + each worker's peak (an upper bound)

    @property
    def partial(self) -> bool:
        return self.units_done < self.units_total


@dataclass
class RenderResult:
    image: np.ndarray  # (H, W, 3) float32, linear, row 0 at the top
    stats: RenderStats = field(default_factory=RenderStats)


def image_bytes(width: int, height: int) -> int:
    """Memory the image itself needs, whatever the budget: the film (float64
    sums, uint32 counts), the float32 result and its 8-bit encoding."""
    return width * height * (3 * 8 + 4 + 3 * 4 + 3)


def capacity_for(memory: int, workers: int) -> int:
    """Paths in flight per worker so all workers fit in ``memory`` bytes."""
    per_worker = memory // max(1, workers) - BASE_PROCESS_BYTES
    return int(np.clip(per_worker // BYTES_PER_PATH, MIN_CAPACITY, MAX_CAPACITY))


def plan_tasks(units: list[Unit], capacity: int, workers: int = 1) -> list[list[Unit]]:
    """Consecutive units grouped into tasks that shrink towards the end.

    Guided scheduling: each task takes about 1/(2 * workers) of the samples
    still unplanned (at most TASK_WAVEFRONTS wavefronts, at least one), so
    the first tasks are long and keep every wavefront full, and the last are
    short so no worker finishes long before the others.  Tiles differ in cost
    (sky is cheap), and with four equal tasks one worker of W2 idled for up
    to a fifth of the wall time.
    Grouping never changes the image: units are merged in order.
    """
    remaining = sum(unit.size for unit in units)
    tasks, current, size = [], [], 0
    target = 0
    for unit in units:
        if not current:
            target = min(TASK_WAVEFRONTS * capacity, max(capacity, remaining // (2 * workers)))
        current.append(unit)
        size += unit.size
        if size >= target:
            tasks.append(current)
            remaining -= size
            current, size = [], 0
    if current:
        tasks.append(current)
    return tasks


def tune_allocator() -> None:
    """Keep freed wavefront temporaries in the heap instead of unmapping them.

    glibc serves every allocation above its mmap threshold (128 KiB at
    first) with a fresh ``mmap`` and returns it with ``munmap``, so a 64 Ki
    path wavefront faulted in every temporary again on every bounce: a fifth
    of the render time went to the kernel (``benchmarks/bench.py --section capacity``).
    Raising the thresholds makes the heap reuse those pages; the peak
    resident memory is unchanged.  No-op where glibc is absent.
    """
    try:
        import ctypes

        libc = ctypes.CDLL("libc.so.6")
    except OSError:
        return
    m_trim_threshold, m_mmap_threshold = -1, -3
    libc.mallopt(m_mmap_threshold, 32 * MiB)  # glibc's maximum on 64-bit
    libc.mallopt(m_trim_threshold, 256 * MiB)


# --- work done in a worker (or inline) --------------------------------------

_WORKER: dict = {}


def _init_worker(scene: Scene, capacity: int, compiled: CompiledScene | None = None, key=None) -> None:
    # The parent decides what an interrupt means; workers just get
    # terminated.  A forked worker inherits the parent's Python handlers, and
    # one that caught SIGTERM would make Pool.terminate() wait forever.
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    tune_allocator()
    compiled = compiled if compiled is not None else scene.compile()
    key = key if key is not None else scene_key(scene.render.seed)
    _WORKER.update(compiled=compiled, capacity=capacity, key=key)


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
    return job.reduce(radiance), stats, (os.getpid(), _peak_rss())


def run_task(units: list[Unit]):
    """:func:`execute` with the scene this process was initialised with."""
    return execute(_WORKER["compiled"], _WORKER["key"], _WORKER["capacity"], units, _WORKER.get("should_stop"))


def _peak_rss() -> int:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024


class Film:
    """Per-pixel sums and sample counts, filled in unit order."""

    def __init__(self, width: int, height: int):
        self.width, self.height = width, height
        self.sum = np.zeros((3, width * height))
        # uint32: 4 bytes a pixel instead of 8 (a 4K film is 33 MB less)
        self.count = np.zeros(width * height, dtype=np.uint32)

    def add(self, unit: Unit, total: np.ndarray, count: np.ndarray) -> None:
        pixels = unit.pixel_index(self.width)
        self.sum[:, pixels] += total
        self.count[pixels] += count.astype(np.uint32)

    def image(self) -> np.ndarray:
        """Mean of each pixel's samples, (H, W, 3) float32; 0 where none."""
        out = np.zeros((self.height, self.width, 3), dtype=np.float32)
        flat = out.reshape(-1, 3)
        rows = 1 << 20
        for start in range(0, self.count.size, rows):
            c = self.count[start:start + rows]
            with np.errstate(invalid="ignore", divide="ignore"):
                mean = np.where(c > 0, self.sum[:, start:start + rows] / c, 0.0)
            # a finite float64 mean can exceed float32: clamp, never store inf
            flat[start:start + rows] = np.minimum(mean, FLOAT32_MAX).T
        return out


def render(scene: Scene, **options) -> np.ndarray:
    """Render ``scene``; returns the linear float32 image of shape (H, W, 3).

    Keyword arguments are those of :func:`render_scene`.
    """
    return render_scene(scene, **options).image


class RenderInterrupted(Exception):
    """Raised inside a task when the render was asked to stop."""


class CheckpointError(ValueError):
    """A checkpoint file cannot be used to resume this render."""


def scene_fingerprint(scene: Scene) -> str:
    """Identifies everything that decides the image (scene, size, samples, seed)."""
    return hashlib.sha256(repr(scene).encode()).hexdigest()


def save_checkpoint(path: str, scene: Scene, film: Film, units_done: int) -> None:
    """Write the film and the number of units merged so far, atomically."""
    directory = os.path.dirname(os.path.abspath(path))
    fd, tmp = tempfile.mkstemp(prefix=".wavefront-checkpoint-", suffix=".npz", dir=directory)
    try:
        with os.fdopen(fd, "wb") as f:
            np.savez(f, fingerprint=scene_fingerprint(scene), units_done=units_done,
                     sum=film.sum, count=film.count)
        publish(tmp, path)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        raise


def load_checkpoint(path: str, scene: Scene) -> tuple[Film, int]:
    """The film and units done of a checkpoint made by the same render."""
    try:
        with np.load(path, allow_pickle=False) as data:
            fingerprint, units_done = str(data["fingerprint"]), int(data["units_done"])
            film_sum, count = data["sum"], data["count"]
    except (OSError, ValueError, KeyError, zipfile.BadZipFile) as e:
        raise CheckpointError(f"{path}: not a wavefront checkpoint ({e})") from None
    if fingerprint != scene_fingerprint(scene):
        raise CheckpointError(f"{path}: made by a different scene or different settings; "
                              "resume with the same scene file and flags")
    film = Film(scene.width, scene.height)
    if film_sum.shape != film.sum.shape or count.shape != film.count.shape:
        raise CheckpointError(f"{path}: image size does not match")
    film.sum[...] = film_sum
    film.count[...] = count
    return film, units_done


def render_scene(scene: Scene, *, workers: int | None = None, memory: int = DEFAULT_MEMORY,
                 chunk_size: int | None = None, progress=None, should_stop=None,
                 checkpoint: str | None = None, checkpoint_interval: float = 30.0,
                 resume: str | None = None, executor=None) -> RenderResult:
    """Render with full control and statistics.

    Parameters
    ----------
    scene : Scene
    workers : int, optional
        Processes to use; default all cores.  The image does not depend on it.
    memory : int
        Memory budget in bytes for the whole render; sets the wavefront size.
    chunk_size : int, optional
        Paths in flight per worker, overriding the budget (tests use it to
        show the image does not depend on it).
    progress : callable(samples_done: int, samples_total: int), optional
    should_stop : callable() -> bool, optional
        Polled several times a second; when it returns True the render stops
        and returns the samples finished so far (``stats.partial``).
    checkpoint : str, optional
        File to save progress to every ``checkpoint_interval`` seconds and
        when the render ends or stops.
    resume : str, optional
        A checkpoint of the same scene and settings to continue from; the
        result is identical to an uninterrupted render.
    executor : callable, optional
        ``executor(scene, capacity, tasks, merge, stopped)`` runs the tasks
        somewhere else (see :mod:`wavefront.distributed`) and calls ``merge``
        with each task's result in task order.  Default: inline for one
        worker, a local process pool for more.

    Raises
    ------
    CheckpointError
        If ``resume`` is not a checkpoint of this render.
    """
    start = time.perf_counter()
    tune_allocator()
    workers = max(1, workers if workers is not None else (os.cpu_count() or 1))
    capacity = chunk_size if chunk_size is not None else capacity_for(
        memory - image_bytes(scene.width, scene.height), workers)
    units = plan_units(scene.width, scene.height, scene.render.samples_per_pixel)
    if resume is not None:
        film, first_unit = load_checkpoint(resume, scene)
    else:
        film, first_unit = Film(scene.width, scene.height), 0
    # Units are merged strictly in order, so "the first k units" describes
    # any partial state exactly; resuming merges the rest in the same order.
    tasks = plan_tasks(units[first_unit:], capacity, workers)
    workers = max(1, min(workers, len(tasks)))
    stats = RenderStats(seed=scene.render.seed, units_done=first_unit, units_total=len(units),
                        workers=workers, capacity=capacity)
    total_samples = sum(u.size for u in units)
    done_samples = sum(u.size for u in units[:first_unit])
    worker_peaks: dict[int, int] = {}
    last_save = time.monotonic()

    def merge(result) -> None:
        nonlocal last_save, done_samples
        unit_results, trace_stats, peak = result
        for unit, total, count, dropped in unit_results:
            film.add(unit, total, count)
            stats.dropped += dropped
            stats.units_done += 1
            done_samples += unit.size
        stats.samples += trace_stats.samples
        stats.segments += trace_stats.segments
        pid, rss = peak
        worker_peaks[pid] = max(worker_peaks.get(pid, 0), rss)
        if progress is not None:
            progress(done_samples, total_samples)
        if checkpoint is not None and time.monotonic() - last_save >= checkpoint_interval:
            save_checkpoint(checkpoint, scene, film, stats.units_done)
            last_save = time.monotonic()

    stopped = lambda: should_stop is not None and bool(should_stop())  # noqa: E731
    try:
        if executor is not None:
            executor(scene, capacity, tasks, merge, stopped)
        elif workers == 1:
            _run_inline(scene, capacity, tasks, merge, stopped)
        else:
            _run_pool(scene, capacity, tasks, merge, stopped, workers)
    except RenderInterrupted:
        pass
    if checkpoint is not None:
        save_checkpoint(checkpoint, scene, film, stats.units_done)
    parent = _peak_rss()
    worker_peaks.pop(os.getpid(), None)  # inline tasks ran in this process
    stats.peak_memory = parent + sum(worker_peaks.values())
    image = film.image()
    stats.elapsed = time.perf_counter() - start
    return RenderResult(image, stats)


POLL_SECONDS = 0.1  # how often a waiting parent checks for a stop request


def _run_inline(scene, capacity, tasks, merge, stopped) -> None:
    saved = dict(_WORKER)
    _WORKER.update(compiled=scene.compile(), capacity=capacity, key=scene_key(scene.render.seed),
                   should_stop=stopped)
    try:
        for task in tasks:
            if stopped():
                raise RenderInterrupted
            merge(run_task(task))
    finally:
        _WORKER.clear()
        _WORKER.update(saved)


def _run_pool(scene, capacity, tasks, merge, stopped, workers) -> None:
    fork = "fork" in multiprocessing.get_all_start_methods()
    ctx = multiprocessing.get_context("fork" if fork else "spawn")
    # Forked workers inherit the scene compiled and the key derived here:
    # doing both in each of them (first imports of the BVH and of
    # numpy.random included) held back the first tasks by ~40 ms, 8 % of W2.
    compiled, key = (scene.compile(), scene_key(scene.render.seed)) if fork else (None, None)
    pool = ctx.Pool(workers, initializer=_init_worker, initargs=(scene, capacity, compiled, key))
    try:
        results = pool.imap(run_task, tasks)  # in task order: the merge order is fixed
        for _ in tasks:
            while True:
                if stopped():
                    raise RenderInterrupted
                try:
                    result = results.next(timeout=POLL_SECONDS)
                    break
                except multiprocessing.TimeoutError:
                    continue
            merge(result)
    finally:
        pool.terminate()
        pool.join()
