"""The render driver: units of work, the local process pool, the film.

The render is a fixed list of units (:mod:`wavefront.film`) grouped into
tasks of a few wavefronts' worth of samples.  Tasks run inline or on a process
pool; their results are merged in task order, so the image does not depend on
the worker count, and the chunk size (wavefront capacity) only decides how
many paths are in flight, never which random numbers a path sees.
"""

from __future__ import annotations

import multiprocessing
import os
import resource
import signal
import time
from dataclasses import dataclass, field

import numpy as np

from .film import Job, Unit, plan_units
from .path import TraceStats, trace_paths
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


def capacity_for(memory: int, workers: int) -> int:
    """Paths in flight per worker so all workers fit in ``memory`` bytes."""
    per_worker = memory // max(1, workers) - BASE_PROCESS_BYTES
    return int(np.clip(per_worker // BYTES_PER_PATH, MIN_CAPACITY, MAX_CAPACITY))


def plan_tasks(units: list[Unit], capacity: int) -> list[list[Unit]]:
    """Consecutive units grouped so each task keeps a wavefront busy."""
    target = TASK_WAVEFRONTS * capacity
    tasks, current, size = [], [], 0
    for unit in units:
        current.append(unit)
        size += unit.size
        if size >= target:
            tasks.append(current)
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


def _init_worker(scene: Scene, capacity: int) -> None:
    # The parent decides what an interrupt means; workers just get terminated.
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    tune_allocator()
    _WORKER.update(compiled=scene.compile(), capacity=capacity, key=scene_key(scene.render.seed))


def run_task(units: list[Unit]):
    """Render the units of one task; returns per-unit results and counters."""
    cs: CompiledScene = _WORKER["compiled"]
    scene = cs.scene
    job = Job(units, scene.width, scene.render.samples_per_pixel)
    stats = TraceStats()
    if scene.render.integrator == "whitted":
        from .whitted import trace_whitted

        radiance = trace_whitted(cs, job, _WORKER["key"], _WORKER["capacity"], stats)
    else:
        radiance = trace_paths(cs, job, _WORKER["key"], _WORKER["capacity"], stats)
    return job.reduce(radiance), stats, (os.getpid(), _peak_rss())


def _peak_rss() -> int:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024


class Film:
    """Per-pixel sums and sample counts, filled in unit order."""

    def __init__(self, width: int, height: int):
        self.width, self.height = width, height
        self.sum = np.zeros((3, width * height))
        self.count = np.zeros(width * height, dtype=np.int64)

    def add(self, unit: Unit, total: np.ndarray, count: np.ndarray) -> None:
        pixels = unit.pixel_index(self.width)
        self.sum[:, pixels] += total
        self.count[pixels] += count

    def image(self) -> np.ndarray:
        """Mean of each pixel's samples, (H, W, 3) float32; 0 where none."""
        out = np.zeros((self.height, self.width, 3), dtype=np.float32)
        flat = out.reshape(-1, 3)
        rows = 1 << 20
        for start in range(0, self.count.size, rows):
            c = self.count[start:start + rows]
            with np.errstate(invalid="ignore", divide="ignore"):
                mean = np.where(c > 0, self.sum[:, start:start + rows] / c, 0.0)
            flat[start:start + rows] = mean.T
        return out


def render(scene: Scene, **options) -> np.ndarray:
    """Render ``scene``; returns the linear float32 image of shape (H, W, 3).

    Keyword arguments are those of :func:`render_scene`.
    """
    return render_scene(scene, **options).image


def render_scene(scene: Scene, *, workers: int | None = None, memory: int = DEFAULT_MEMORY,
                 chunk_size: int | None = None, progress=None, should_stop=None) -> RenderResult:
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
        Polled between tasks; when it returns True the render stops early and
        returns the samples finished so far (``stats.partial``).
    """
    start = time.perf_counter()
    tune_allocator()
    workers = max(1, workers if workers is not None else (os.cpu_count() or 1))
    capacity = chunk_size if chunk_size is not None else capacity_for(memory, workers)
    units = plan_units(scene.width, scene.height, scene.render.samples_per_pixel)
    tasks = plan_tasks(units, capacity)
    workers = min(workers, len(tasks))
    film = Film(scene.width, scene.height)
    stats = RenderStats(seed=scene.render.seed, units_total=len(units), workers=workers, capacity=capacity)
    total_samples = sum(u.size for u in units)
    worker_peaks: dict[int, int] = {}

    def merge(result) -> None:
        unit_results, trace_stats, peak = result
        for unit, total, count, dropped in unit_results:
            film.add(unit, total, count)
            stats.dropped += dropped
            stats.units_done += 1
        stats.samples += trace_stats.samples
        stats.segments += trace_stats.segments
        pid, rss = peak
        worker_peaks[pid] = max(worker_peaks.get(pid, 0), rss)
        if progress is not None:
            progress(stats.samples, total_samples)

    stopped = lambda: should_stop is not None and should_stop()  # noqa: E731
    if workers == 1:
        saved = dict(_WORKER)
        _WORKER.update(compiled=scene.compile(), capacity=capacity, key=scene_key(scene.render.seed))
        try:
            for task in tasks:
                if stopped():
                    break
                merge(run_task(task))
        finally:
            _WORKER.clear()
            _WORKER.update(saved)
    else:
        ctx = multiprocessing.get_context("fork" if "fork" in multiprocessing.get_all_start_methods() else "spawn")
        pool = ctx.Pool(workers, initializer=_init_worker, initargs=(scene, capacity))
        try:
            for result in pool.imap(run_task, tasks):
                merge(result)
                if stopped():
                    break
        finally:
            pool.terminate()
            pool.join()
    parent = _peak_rss()
    worker_peaks.pop(os.getpid(), None)  # inline tasks ran in this process
    stats.peak_memory = parent + sum(worker_peaks.values())
    image = film.image()
    stats.elapsed = time.perf_counter() - start
    return RenderResult(image, stats)
