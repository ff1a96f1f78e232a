"""Memory: what this process holds and has held, and the budget's error.

At the bottom of the package so the scene loader can refuse a file it cannot
load within the budget before reading it, as the render driver does for the
render (see :mod:`wavefront.render`).
"""

from __future__ import annotations

import math
import os
import resource

MiB = 1024 * 1024


class MemoryBudgetError(ValueError):
    """The render cannot fit in the memory budget at all."""


def libc():
    """The C library, for glibc's allocator knobs and ``prctl``; None where absent."""
    try:
        import ctypes

        return ctypes.CDLL("libc.so.6", use_errno=True)
    except OSError:
        return None


HUGE_PAGE = 2 * MiB  # x86-64's and arm64's transparent huge page
MADV_HUGEPAGE = 14  # <sys/mman.h> (Linux)
# Each piece is below the mmap threshold render.tune_allocator sets (32 MiB),
# so glibc carves it from the heap instead of mapping it apart.
HEAP_PIECE = 16 * MiB


def reserve_heap(nbytes: int) -> None:
    """Grow the heap by about ``nbytes`` and ask for transparent huge pages on it.

    A fresh worker faults in every page of its wavefront's temporaries once:
    ~4,000 faults of 4 KiB for a 32 Ki path task, ~1 us each on this VM, a
    tenth of a 4 spp Cornell render's task.  The heap grown here is freed at
    once, but stays mapped (the trim threshold is raised too), so the
    temporaries are carved from it and fault in 2 MiB at a time.  Nothing is
    touched here: memory is only used where the render writes, as before.

    Only the range the heap's top grew by is advised: glibc may place pieces
    in free holes of the heap inherited from the parent (a big mesh's
    scene leaves some), and advising those would take in the parent's live
    pages around them.  No-op without glibc, ``sbrk`` or ``madvise``.
    """
    lib = libc()
    if lib is None or nbytes <= 0 or not all(hasattr(lib, name) for name in ("madvise", "sbrk")):
        return
    import ctypes

    malloc, free, madvise, sbrk = lib.malloc, lib.free, lib.madvise, lib.sbrk
    malloc.restype, malloc.argtypes = ctypes.c_void_p, [ctypes.c_size_t]
    free.restype, free.argtypes = None, [ctypes.c_void_p]
    madvise.argtypes = [ctypes.c_void_p, ctypes.c_size_t, ctypes.c_int]
    sbrk.restype, sbrk.argtypes = ctypes.c_void_p, [ctypes.c_ssize_t]
    pieces = []
    try:
        top = sbrk(0)
        while len(pieces) * HEAP_PIECE < nbytes and (piece := malloc(HEAP_PIECE)):
            pieces.append(piece)
        grown = sbrk(0)
        if top and grown:
            start = -(-top // HUGE_PAGE) * HUGE_PAGE  # whole huge pages of the new range
            end = grown // HUGE_PAGE * HUGE_PAGE
            if end > start:
                madvise(start, end - start, MADV_HUGEPAGE)  # advice: a failure changes nothing
    finally:
        for piece in reversed(pieces):
            free(piece)


def current_rss() -> int:
    """This process's resident memory now, in bytes."""
    try:
        with open("/proc/self/statm") as f:
            return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE")
    except (OSError, ValueError, IndexError):
        return peak_rss()


def peak_rss() -> int:
    """This process's peak resident memory since start (or the last reset)."""
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024


def _vm_hwm() -> int | None:
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith("VmHWM:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError):
        pass
    return None


def phase_peak(reset: bool = True) -> int:
    """Peak resident memory of this process since the last call, then reset.

    Linux resets the high-water mark on writing 5 to ``/proc/self/clear_refs``;
    where that fails the peak since start is returned (an upper bound).
    """
    value = _vm_hwm()
    if value is None:
        return peak_rss()
    if reset:
        try:
            with open("/proc/self/clear_refs", "w") as f:
                f.write("5")
        except OSError:
            pass
    return value


def release_free_memory() -> None:
    """Hand freed heap pages back to the kernel (glibc ``malloc_trim``), so a
    forked worker does not inherit, and count, the parent's garbage."""
    lib = libc()
    if lib is not None and hasattr(lib, "malloc_trim"):
        lib.malloc_trim(0)


def physical_memory() -> int:
    """Memory this machine (or this cgroup, if it has a lower limit) can give."""
    try:
        total = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    except (ValueError, OSError):
        return 1 << 62
    for limit in ("/sys/fs/cgroup/memory.max", "/sys/fs/cgroup/memory/memory.limit_in_bytes"):
        try:
            with open(limit) as f:
                text = f.read().strip()
            if text.isdigit():
                total = min(total, int(text))
        except OSError:
            pass
    return total


def refuse_unless_fits(memory: int, need: int, what: str) -> None:
    """Raise :class:`MemoryBudgetError` if ``need`` more bytes on top of this
    process's current memory exceed ``memory``."""
    held = current_rss()
    if held + need > memory:
        total, budget = over_budget(held + need, memory)
        raise MemoryBudgetError(f"{what} needs about {mib(need)} more than the {mib(held)} "
                                f"this process holds: {total} in all, more than the "
                                f"memory budget of {budget}")


def mib(size: int) -> str:
    """``size`` in MiB for a message: one decimal below 10 MiB, whole above."""
    return f"{size / MiB:,.1f} MiB" if size < 10 * MiB else f"{size / MiB:,.0f} MiB"


def over_budget(total: int, budget: int) -> tuple[str, str]:
    """``total`` and ``budget`` in MiB for a message that the one is more than
    the other: as :func:`mib` gives them if that shows it, else with the
    fewest decimals (to 3) that do, and at 3 the total rounded up and the
    budget down.  Rounded alike to whole MiB, a total 0.1 MiB over its budget
    read "135 MiB in all, more than the memory budget of 135 MiB"."""
    if total > budget:
        for digits in range(4):
            shown = [round(size / MiB, max(digits, size < 10 * MiB)) for size in (total, budget)]
            if shown[0] > shown[1]:
                if digits == 0:
                    return mib(total), mib(budget)
                return f"{shown[0]:,.{digits}f} MiB", f"{shown[1]:,.{digits}f} MiB"
        return f"{math.ceil(total / MiB * 1000) / 1000:,.3f} MiB", f"{math.floor(budget / MiB * 1000) / 1000:,.3f} MiB"
    return mib(total), mib(budget)


# The scene loader's peak per byte of YAML, measured with ``benchmarks/bench.py
# --section budget`` (200,000 and 1,000,000 spheres): a scene file too big to
# load within a budget is refused before it is parsed.
LOAD_BYTES_PER_FILE_BYTE = 8
MIN_MEMORY = 64 * MiB  # the interpreter and NumPy alone take ~40 MiB


def check_budget(memory) -> int:
    """A memory budget in bytes: an integer from ``MIN_MEMORY`` to this
    machine's memory (the same rule as ``--memory``).  Raises ValueError."""
    if isinstance(memory, bool) or not isinstance(memory, int):
        raise ValueError(f"memory: expected a number of bytes, got {memory!r}")
    if memory < MIN_MEMORY:
        raise ValueError(f"memory: at least {MIN_MEMORY // MiB} MiB is needed, got {memory:,} bytes")
    physical = physical_memory()
    if memory > physical:
        raise ValueError(f"memory: {memory / 2**30:,.1f} GiB is more than this machine's memory "
                         f"({physical / 2**30:,.1f} GiB)")
    return memory
