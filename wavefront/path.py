"""The wavefront path integrator (backward path tracing, RTIOW books 1-2).

One call to :func:`trace_paths` runs a job's samples through a fixed-capacity
wavefront (and, given a :class:`TaskStream`, the samples of every task that
arrives before the wavefront has drained: see :func:`hand_over`).  Each
iteration is a list of named stages over *all* live paths:

1. **refill** free slots with camera rays of new samples (so a long tail of a
   few deep paths never costs a near-empty NumPy call per bounce);
2. **intersect** every path with every shape (brute force or the BVH), and
   describe each hit in one :class:`~wavefront.shapes.SurfaceHits`;
   **media** (scenes with participating media, :func:`travel_media`): free
   flight through the media between each path's vertex and its hit,
   crossing invisible boundaries; paths that scatter in a medium take
   stages 5-9 there (:func:`scatter_in_media`; their shadow rays join the
   surfaces' in stage 6) and rejoin at 9;
3. **escaped** paths add ``throughput * background`` and end;
4. **emitted**: paths that hit an emitter end; those that struck its front
   side add ``throughput * color``;
5. **sample lights** (``render.light_sampling``): at every diffuse hit,
   one point on an emitter, and a shadow ray towards it;
6. **trace shadow rays**: their own batch and stage, through the any-hit
   query; unoccluded ones add their MIS-weighted contribution (where paths
   are few, the next bounce's stage 2 answers it: see
   :func:`intersect_with_shadows`);
7. **scatter**: hits are routed by material kind, one kernel per kind
   present, and throughput is multiplied by the attenuation; absorbed paths
   end, and so do paths that have reached ``max_depth`` segments;
8. **roulette** (``render.russian_roulette``) ends some paths past its depth;
9. **compact** the survivors.

A path ends in one of the book's three ways: it hits a light, escapes to the
background, or reaches the depth limit (contributing nothing more); in a
scene with media also where a black medium absorbs it.

Participating media (:mod:`wavefront.media`): a vertex in a medium is lit
like a diffuse one, the isotropic phase function ``1 / (4 pi)`` standing in
for the BSDF and its pdf, and every shadow ray is attenuated by the
transmittance of the media it crosses.  Free-flight distances are sampled
analogly (with probability the transmittance), so a light reached through
fog carries no transmittance factor and its MIS weight compares the same two
pdfs as on a surface.

Next-event estimation with multiple importance sampling (Veach 1997, ch. 9;
pbrt-v4's wavefront ``SampleDirect``/``TraceShadowRays``; Mitsuba's ``path``)
lights each lambertian vertex twice: by the light sample, weighted
``p_light^2 / (p_light^2 + p_material^2)`` (the power heuristic), and by the
material's own sample when it happens to hit an emitter, weighted the other
way.  The two weights of any one light path sum to one, so the expectation is
the book estimator's and only the noise changes.  Mirrors and glass are deltas
(no light sample can land on their one direction): their emission hits count
in full, as do those seen straight from the camera.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np

from .batch import PathBatch, ShadowBatch
from .units import Job
from .materials import LazyUniforms, lambertian_pdf, scatter_dielectric, scatter_lambertian, scatter_metal
from .media import ISOTROPIC_PDF, cross, current_medium, medium_albedo, transmittance
from .sampling import (CROSSINGS_PER_SEGMENT, TIME_PAIR, Sampler, bounce_dimension, light_choice_dimension,
                       light_point_dimension, medium_dimension, random_unit_vector)
from .geometry import T_MIN
from .scene import CompiledScene
from .shapes import Hits
from .vecmath import TAKE_MODE, dot, gather, scatter, scatter_add, true_rows

REFILL_FRACTION = 0.5  # refill once fewer than half the slots are live
# Paths that escape are left in the batch, marked absorbed, while they are at
# most this fraction of it (see escaped): compacting every field then costs
# more than carrying them through one bounce's elementwise stages.
ESCAPED_KEPT_FRACTION = 1.0 / 8.0
# ... unless the kernels other than the one serving most hits serve at least
# this share of them: the hits are then grouped by kernel all the same (see
# escaped), since running the main kernel over every row, and the others over
# gathered rows, costs more than the compaction.  W1's camera bounces (~10 %
# escaped, 32-50 % glass and metal) are grouped: its stages after the hit
# query 5.9 % faster (median of 20 interleaved runs over 40 captured bounces);
# cornell_spheres' (9-25 % outside its walls' kernel) keep their escaped paths.
GROUPED_OTHER_SHARE = 0.3
# The search for media boundaries along a piece of a segment starts this far
# before the piece (a vertex, or the boundary just crossed): a boundary
# closer than T_MIN past a ray's origin is skipped, so starting on the
# crossing itself missed any other boundary within T_MIN beyond it (where two
# media's boundaries meet: one sample in a thousand lost its way in a
# unit-sized scene).  Now only those within T_MIN - RESTART_BACKOFF (1e-6)
# are missed; the boundary just crossed (or a surface's own boundary at a
# vertex) lies within T_MIN and is skipped (were rounding to find it again,
# crossing it again from the same side changes nothing).
RESTART_BACKOFF = T_MIN * (1.0 - 1e-3)
# A boundary less than this before a segment's hit counts as lying on the
# surface, which wins: fog resting on a floor (a box boundary's bottom face
# in the floor's plane) is left only through its sides, whatever the rounding
# of a distance measured from a restart point.  The same 1e-6 as above.
COINCIDENT = T_MIN - RESTART_BACKOFF
# Every segment's first boundary search (a camera ray's, a scattered ray's,
# a shadow ray's) starts this far behind its origin, so that it finds a
# boundary up to T_MIN behind it, at it or just in front (RESTART_BACKOFF
# would skip those within 1e-6): a camera on a boundary looking in saw
# through the fog (its point test puts it outside), and a path refracted
# through glass whose fog boundary lay within 1e-6 of the glass (not exactly
# on it: see media.py's interfaces) never entered the fog, the boundary being
# "on the surface" before the hit and skipped after it.  Crossing a boundary
# just behind the origin leaves the mask as it is just beyond it along the
# ray: right whichever side the origin is on, and a no-op when it was right
# already (crossings set or clear a bit, idempotently).  Such a piece is
# clamped to start at the origin, so nothing scatters behind it.
FIRST_BACKOFF = 2.0 * T_MIN
# A shadow ray stops this fraction short of the light's surface, so that it
# cannot find the emitter itself (pbrt's ShadowEpsilon); a blocker closer to
# the light than that is missed, 1e-4 of the distance.
SHADOW_EPSILON = 1e-4
# Roulette never keeps a path with certainty (Mitsuba's cap): a path whose
# throughput stays near 1 (a white furnace) still ends in finite time.
ROULETTE_MAX_SURVIVAL = 0.95
# A hit query in a medium stops this fraction (plus T_MIN) past the first
# free-flight distance (intersect_in_media): far above float32 rounding
# (6e-8), so the cap lies past the distance in any precision.
FLIGHT_CAP_SLACK = 1e-6
# A bounce's shadow rays join the next bounce's nearest-hit query (see
# trace_paths) while the two together are at most this many rays.
RIDING_RAYS = 2048
# Streaming (see hand_over): the most tasks whose samples share a wavefront.
# A task is handed back only when its last path ends, so one long path (glass
# without roulette, up to max_depth bounces) would otherwise hold every task
# after it, and their per-sample radiance, in memory: at this bound the
# wavefront drains as it did before streaming.  A task's samples are issued
# over ~20 bounces, and W1's glass and metal paths often live longer: with
# two, W1's workers still drained ~9 times each (two of every three tasks);
# with three, about once a render in one worker (a straggler of its oldest
# task holding the two after it, session 10), ~6-10 ms: less than a fourth
# task's store would cost in first writes (+13 MB a worker on W1).
HELD_TASKS = 3
# A bounce of at most this many paths draws their light, bounce and roulette
# uniforms together, in one call (see draw_together).
TOGETHER_PATHS = 2048
# Where at most this fraction of a bounce's paths end, the survivors past the
# end of the compacted batch move into the rows of the ended (see advance)
# rather than every field being compacted.
FILLED_FRACTION = 1.0 / 8.0


@dataclass
class TraceStats:
    segments: int = 0  # rays traced (camera rays + scattered rays)
    samples: int = 0
    shadow_rays: int = 0  # next-event estimation's shadow rays (not counted in segments)


def render_sampler(cs: CompiledScene, key) -> Sampler:
    """The render's source of uniforms (``render.sampler``) under hash key ``key``."""
    settings = cs.scene.render
    return Sampler(key, settings.samples_per_pixel, settings.sampler)


def camera_paths(cs: CompiledScene, frame, sampler: Sampler, job: Job, start: int, stop: int,
                 pixel_centres: bool = False, before: PathBatch | None = None, mis: bool = True) -> PathBatch:
    """Stage 1: new paths for the job's slots ``start:stop``.

    ``pixel_centres`` puts every sample at its pixel's centre instead of
    jittering it (classic Whitted with one sample per pixel).  ``before``:
    paths in flight, if any: the result is then ``PathBatch.concat(before,
    <the new paths>)``, each new field written once, into its place in the
    joined array (not made on its own and copied again: ~70 bytes a path).
    ``mis``: whether the paths carry what MIS weights read (``bsdf_pdf``,
    ``specular``); without light sampling no stage reads them, and they are
    None (neither made, kept up nor compacted).
    """
    n = stop - start
    m = 0 if before is None else len(before)

    def field(name, dtype, rows=None, value=None):
        old = getattr(before, name) if m else None
        return None if m and old is None else _joined(old, n, dtype, rows, value)  # None in either: None

    # the new paths' rays and states go straight into their columns
    origin, direction, state = field("origin", cs.dtype, 3), field("direction", cs.dtype, 3), field("state", np.uint64)
    exact = origin.dtype == cs.dtype  # else the rays are rounded to the render's precision first, as they always were
    pos = m
    for size, pixel, new_state, u, lens in _new_samples(sampler, job, start, stop, frame.has_defocus):
        rows = slice(pos, pos + size)
        state[rows] = new_state
        if pixel_centres:
            u = np.full(u.shape, 0.5)
        # in float64, then rounded to the render's precision
        rays = frame.generate_rays(pixel, u, lens, cs.dtype, (origin[:, rows], direction[:, rows]) if exact else None)
        if not exact:
            origin[:, rows], direction[:, rows] = rays
        pos = rows.stop
    # motion blur (RTOW book 2): the camera ray's time, from its own pair;
    # only a scene with something moving draws it
    time = sampler.uniform(state[m:], TIME_PAIR, 0) if cs.shapes.moving else None
    media = cs.media
    return PathBatch(
        origin=origin,
        direction=direction,
        throughput=field("throughput", cs.dtype, 3, 1),
        slot=field("slot", np.int64, value=np.arange(start, stop, dtype=np.int64)),
        state=state,
        depth=field("depth", np.int32, value=0),
        bsdf_pdf=field("bsdf_pdf", np.float64, value=0.0) if mis else None,
        specular=field("specular", bool, value=True) if mis else None,  # seen from the camera: emission counts in full
        eta_scale=field("eta_scale", np.float64, value=1.0),
        time=None if time is None else field("time", np.float64, value=time),
        # camera rays start in the media around the camera
        media_mask=None if media is None else field("media_mask", np.uint64, value=media.camera_mask),
    )


# A refill whose units have at least this many samples a pixel makes its new
# paths' states and camera pairs unit by unit, as grids of pixels and sample
# indices (each pixel's and each index's words made once: see
# Sampler.start_grid); one with fewer, path by path (a grid of few samples
# saves little, and the first passes' units are small: a refill of 40 Ki
# paths spans ten of them, and a trace of one sample a pixel took 5.6 % longer
# unit by unit, ~300 NumPy calls a unit).
GRID_MIN_SAMPLES = 8


def _new_samples(sampler: Sampler, job: Job, start: int, stop: int, defocus: bool):
    """The new paths of slots ``start:stop``, in pieces of consecutive slots:
    each piece's size, pixels (size,), states (size,) and camera pairs (the
    pixel jitter, and the lens sample or None for a pinhole, which never
    reads it: not drawing it changes no number), each (2, size)."""
    blocks = job.blocks(start, stop)  # a unit's slots: a grid of pixels and sample indices
    if all(block.sample_stop - block.sample_start >= GRID_MIN_SAMPLES for block in blocks):
        for block in blocks:
            grid = sampler.start_grid(block.pixel, block.sample_start, block.sample_stop)
            yield (block.size, block.repeated(block.pixel), block.flattened(grid),
                   block.flattened(sampler.pairs_grid(grid, 0)),
                   block.flattened(sampler.pairs_grid(grid, 1)) if defocus else None)
        return
    pixel, sample_id = job.samples(start, stop)
    state = sampler.start(pixel, sample_id)
    yield stop - start, pixel, state, sampler.pairs(state, 0), sampler.pairs(state, 1) if defocus else None


def _joined(old, n, dtype, rows=None, value=None):
    """A batch field: ``old``'s columns (or none: ``old`` None), then ``n``
    new ones set to ``value`` (cast as astype would; left unset for None),
    of ``dtype`` promoted with ``old``'s (``rows``: a (rows, N) field, else
    (N,)), written once each, where PathBatch.concat of a batch of the new
    paths made on its own would copy them again (~70 bytes a path)."""
    m = 0 if old is None else old.shape[-1]
    dtype = dtype if old is None else np.result_type(old.dtype, dtype)
    out = np.empty((m + n,) if rows is None else (rows, m + n), dtype=dtype)
    if m:
        out[..., :m] = old
    if value is not None:
        np.copyto(out[..., m:], value, casting="unsafe")
    return out


# Scatter kernels: ``albedo`` is the rows' textured albedo (3, n), or None to
# gather the material table's plain colour.
# ``out``, if given, takes the new directions (it may be ``d`` itself: each
# kernel reads ``d`` before it writes them).
def _lambertian(table, m, d, n, front_face, u, albedo=None, out=None):
    return scatter_lambertian(d, n, front_face, gather(table.albedo, m) if albedo is None else albedo, u, out)


def _metal(table, m, d, n, front_face, u, albedo=None, out=None):
    return scatter_metal(d, n, front_face, gather(table.albedo, m) if albedo is None else albedo,
                         gather(table.fuzz, m), u, out)


def _dielectric(table, m, d, n, front_face, u, albedo=None, out=None):
    return scatter_dielectric(d, n, front_face, gather(table.refraction_index, m), u, out)


# Which material kinds each scatter kernel serves.  Phong surfaces are
# lambertian with albedo = diffuse under the path integrator.  Metal last: its
# rows are then the last of the grouped hits, after every row whose uniforms
# are drawn up front (see _scatter_runs).
_KERNELS = ((("lambertian", "phong"), _lambertian), (("dielectric",), _dielectric), (("metal",), _metal))


def kernels_present(table):
    """(kind codes, kernel) for the kinds present in the scene only."""
    # a set of the (few) table rows, not np.unique: that imports numpy.ma on
    # first use, ~10 ms of every worker's first task
    present = set(table.kind.tolist())
    out = []
    for kinds, kernel in _KERNELS:
        codes = tuple(c for c in (table.code(k) for k in kinds) if c in present)
        if codes:
            out.append((np.array(codes, dtype=np.int8), kernel))
    return out


@dataclass(slots=True)
class KernelGroups:
    """How stage 3 groups the hits by the scatter kernel that serves them
    (see :func:`escaped`): ``of_hit`` ``(M + 1,)`` int8, read at a hit's
    primitive index plus one, is -1 in its first entry (a miss, primitive
    index -1) and then the index in ``kernels`` of each primitive's kernel,
    ``len(kernels)`` for none (emitters); ``glass`` the index of the
    dielectric kernel, or None.

    Shifted by one so that no lookup index is negative: ``take`` adjusts a
    negative index with a branch, which mispredicts on every other row where
    misses and hits mix (a W1 bounce's ~60 Ki rows: 75 us against 40 for the
    add and a lookup without negatives)."""

    of_hit: np.ndarray
    count: int  # groups: the kernels, and one more if some primitive has none
    glass: int | None

    @classmethod
    def build(cls, cs: CompiledScene, kernels) -> KernelGroups | None:
        """None where there is nothing to group (fewer than two kernels)."""
        if len(kernels) < 2:
            return None
        table = cs.materials
        of_material = np.full(table.kind.shape, len(kernels), dtype=np.int8)
        glass = None
        for k, (codes, _) in enumerate(kernels):
            of_material[np.isin(table.kind, codes)] = k
            if tuple(codes) == (table.code("dielectric"),):
                glass = k
        of_hit = np.concatenate(([np.int8(-1)], of_material.take(cs.shapes.material_idx)))
        # every kernel has a group (and a run), also one no primitive uses: a
        # dielectric material that no shape had was the last kernel, and the
        # glass run it indexed did not exist
        return cls(of_hit, max(len(kernels), int(of_hit.max()) + 1), glass)

    def of(self, primitive_idx) -> np.ndarray:
        """``(N,)`` int8: each row's group, -1 for a miss."""
        return self.of_hit.take(primitive_idx + 1, mode=TAKE_MODE)

    def mixed(self, group) -> bool:
        """Whether the groups other than the largest hold at least
        ``GROUPED_OTHER_SHARE`` of the hits (``group``: :meth:`of`'s)."""
        # a compare and a count per group: 13 us on a W1 bounce, np.bincount 145
        counts = [int(np.count_nonzero(group == k)) for k in range(self.count)]
        return max(counts) < (1.0 - GROUPED_OTHER_SHARE) * sum(counts)

    def order(self, group) -> tuple[np.ndarray, list[tuple[int, int]]]:
        """The rows that hit something, kernel 0's first, then kernel 1's,
        ..., then those of no kernel, each group in batch order; and each
        kernel's run ``(start, stop)`` in that order (``group``: :meth:`of`'s)."""
        rows = [true_rows(group == k) for k in range(self.count)]
        stops = list(itertools.accumulate(r.size for r in rows))  # a few Python ints: no NumPy call
        return (np.concatenate(rows) if rows else true_rows(group >= 0)), list(zip([0] + stops[:-1], stops))


def begin_trace(cs: CompiledScene, job: Job, stats: TraceStats | None):
    """What every integrator starts from: the camera frame, a zeroed
    per-sample radiance buffer and the counters (the job's samples counted)."""
    scene = cs.scene
    stats = stats if stats is not None else TraceStats()
    stats.samples += job.size
    return scene, scene.camera.frame(scene.width, scene.height), np.zeros((3, job.size)), stats


def trace_paths(cs: CompiledScene, job: Job, key, capacity: int, stats: TraceStats | None = None,
                should_stop=None, stream: TaskStream | None = None) -> np.ndarray | None:
    """Radiance of every sample of ``job``; shape ``(3, job.size)``.

    The loop is the list of stages; each is a function over the live
    :class:`PathBatch`.  ``should_stop`` is polled once per bounce; when it
    returns True the trace returns early with incomplete radiance, which the
    caller discards.  With a ``stream``, ``job`` is its first task, and every
    task's radiance and counters are handed to ``stream.finished`` as soon as
    its paths have all ended (see :func:`hand_over`); the trace returns None
    once the wavefront is empty and no task is waiting (``stats`` is then
    only the trace's scratch).
    """
    if stream is None:
        scene, frame, radiance, stats = begin_trace(cs, job, stats)
    else:
        scene, stats, held = cs.scene, TraceStats(), HeldTasks(job)
        frame, radiance = scene.camera.frame(scene.width, scene.height), held.radiance
    kernels = kernels_present(cs.materials)
    groups = KernelGroups.build(cs, kernels)
    settings = scene.render
    sampler = render_sampler(cs, key)
    emitters = cs.emitters if settings.light_sampling and cs.emitters is not None and len(cs.emitters) else None
    roulette = settings.russian_roulette
    table = cs.materials
    # Decided once a trace over the table's few rows, not per bounce: whether
    # some primitive emits (if none, stage 4 has nothing to find: three
    # spheres' lamp is a material no sphere wears), and which materials are
    # sampled with a density
    lit = bool((table.kind.take(cs.shapes.material_idx) == table.code("emissive")).any())
    diffuse_material = diffuse_materials(table)
    mis = emitters is not None  # only emission hits' MIS weights read a path's bsdf_pdf and specular
    live, next_slot = camera_paths(cs, frame, sampler, job, 0, 0, mis=mis), 0
    riding = None  # shadow rays whose any-hit query goes with the next bounce's nearest-hit one
    while True:
        if stream is not None:
            next_slot = hand_over(stream, held, next_slot, live, riding)
            job, radiance = held.job, held.radiance
        live, next_slot = refill(cs, frame, sampler, job, live, next_slot, capacity, mis)
        if len(live) == 0 or (should_stop is not None and should_stop()):
            break
        stats.segments += len(live)
        if stream is not None:
            held.charge(live.slot)
        in_medium = shadows = None
        if cs.media is None:
            if riding is None:
                hits = cs.shapes.intersect(live.origin, live.direction, time=live.time)
            else:
                hits, riding = intersect_with_shadows(cs, live, riding, radiance, stats), None
        else:
            hits, first = intersect_in_media(cs, sampler, live)
            live, hits, in_medium, point = travel_media(cs, sampler, live, hits, first)
            if len(in_medium):
                in_medium, shadows = scatter_in_media(cs, sampler, in_medium, point, emitters)
        live, surface, gone, runs = escaped(cs, live, hits, radiance, groups)
        if len(live):
            drawn = draw_together(cs, sampler, live, emitters, roulette)
            # each hit's material kind, taken once a bounce where a stage reads
            # it (grouped rows and no emitter: none does)
            kind = gather(table.kind, surface.material_idx) if lit or runs is None else None
            if lit:
                absorbed = emitted(cs, live, surface, radiance, emitters, gone, kind)
            else:  # emitted's answer where no primitive emits
                absorbed = np.zeros(len(live), dtype=bool) if gone is None else gone.copy()
            # read by light sampling and MIS (the paths' specular) only
            diffuse = gather(diffuse_material, surface.material_idx) if mis else None
            albedo = surface_albedo(cs, surface)
            if emitters is not None:
                # one any-hit query for the shadow rays of medium and surface vertices alike
                shadows = ShadowBatch.concat(shadows, sample_lights(cs, sampler, emitters, live, surface, diffuse,
                                                                    absorbed, settings.depth, albedo, drawn))
        if len(live):
            direction, absorbed = scatter_hits(cs, sampler, kernels, live, surface, absorbed, albedo, drawn, kind, runs)
            if mis or roulette is not None:  # roulette reads eta_scale
                record_sampling(cs, live, surface, diffuse, direction, kind,
                                None if runs is None else (0, 0) if groups.glass is None else runs[groups.glass])
            if roulette is not None:
                absorbed = russian_roulette(sampler, live, absorbed, roulette.depth, drawn)
            if cs.media is not None:
                cross_interfaces(cs, live, surface, direction, absorbed)
            live = advance(live, surface, direction, absorbed, settings.depth)
        if in_medium is not None:
            live = PathBatch.concat(live, in_medium)
        # Stage 6 (it only adds to the radiance, which no later stage of the
        # bounce reads).  A few rays' any-hit query costs what its ~60 NumPy
        # calls cost whatever the rays, so where paths are few (the tail after
        # roulette) the shadow rays join the next bounce's nearest-hit query
        # instead: a hit nearer than a ray's t_max there is exactly an any-hit
        # (Intersector.occluded's own definition), and their light is added
        # before anything else of the next bounce, so every sample's sum
        # keeps its order, bit for bit.  (No media: their shadow rays also
        # need the transmittance.)
        if shadows is not None and len(shadows):
            if stream is not None:
                held.charge(shadows.slot, shadow_rays=True)
            if cs.media is None and len(live) and len(live) + len(shadows) <= RIDING_RAYS:
                riding = shadows
            else:
                trace_shadow_rays(cs, shadows, radiance, stats)
    if riding is not None:  # the paths all ended: their last shadow rays on their own
        trace_shadow_rays(cs, riding, radiance, stats)
    if stream is None:
        return radiance
    if not (should_stop is not None and should_stop()):
        hand_over(stream, held, next_slot, live, None, take=False)
    return None


class TaskStream:
    """Where a streaming :func:`trace_paths` gets its next task and hands
    back each finished one (a worker's pipe to the parent, or the inline
    render's plan and merge)."""

    def next_job(self, idle: bool) -> Job | None:
        """The next task's samples if one has arrived, else None (without
        waiting).  ``idle``: nothing is in flight (without a task the trace
        ends); else the wavefront has taken every sample and its last paths
        are running."""
        raise NotImplementedError

    def finished(self, job: Job, stats: TraceStats, radiance: np.ndarray) -> None:
        """Task ``job`` is done: ``radiance`` (3, job.size) is final, and
        ``stats`` counts its samples and its own paths' segments and shadow rays."""
        raise NotImplementedError


class HeldTasks:
    """A streaming trace's tasks in flight, oldest first: their units joined
    into one :class:`Job` (one run of slots) and their per-sample radiance, a
    window of one buffer that moves on as tasks leave the front (joining
    buffers copied what was held, ~2 ms a task on W1, 2 % of its time)."""

    def __init__(self, first: Job):
        self.tasks = [first]
        self.job = first
        self.counts = [TraceStats(samples=first.size)]  # each held task's own (see charge)
        # room for the held tasks twice over: the window is moved back to the
        # start (a copy of what it holds) once every few tasks, not every task.
        # Not np.zeros: a task's samples are zeroed as it joins (here and in
        # add), and zeroing the whole store up front wrote every page of it once
        # more, at the worker's start (calloc from the heap memsets: 7-25 ms of
        # W1's 38 MB store, up to 200 ms when the kernel compacts for huge pages).
        self.store = np.empty((3, 2 * HELD_TASKS * max(first.size, 1)))
        self.store[:, :first.size] = 0.0
        self.start = 0

    @property
    def radiance(self) -> np.ndarray:
        """The held samples' radiance, (3, job.size): a view."""
        return self.store[:, self.start:self.start + self.job.size]

    def charge(self, slot: np.ndarray, shadow_rays: bool = False) -> None:
        """Count rays (path segments, or shadow rays) to the tasks whose
        samples they serve, by slot: each task's counts are its own paths',
        the same numbers as when it ran alone, and a task lost with a dead
        worker takes its counts with it."""
        field = "shadow_rays" if shadow_rays else "segments"
        below, end = 0, 0
        last = len(self.tasks) - 1
        for i, (task, counts) in enumerate(zip(self.tasks, self.counts)):  # a few held tasks, not rays
            end += task.size
            up_to = slot.size if i == last else int(np.count_nonzero(slot < end))
            setattr(counts, field, getattr(counts, field) + up_to - below)
            below = up_to

    def pop(self) -> tuple[Job, TraceStats]:
        """The oldest task and its counters, out (its radiance stays readable
        until the next :meth:`add`)."""
        task, stats = self.tasks.pop(0), self.counts.pop(0)
        self.start += task.size
        self.job = Job([u for t in self.tasks for u in t.units], task.width, task.samples_per_pixel)
        return task, stats

    def add(self, task: Job) -> None:
        """Task ``task`` joins at the back, its radiance zero."""
        held, room = self.job.size, self.store.shape[1]
        if self.start + held + task.size > room:
            if held + task.size > room:
                grown = np.empty((3, max(2 * room, held + task.size)))  # zeroed below where it is used
                grown[:, :held] = self.radiance
                self.store = grown
            else:
                # back to the start, channel by channel: a 2-D view's rows
                # interleave in memory, so NumPy copied the held samples to a
                # temporary first even when the ranges are disjoint (as they
                # are unless task sizes differ a lot); a row's copy is one
                # memcpy, half the time (0.9 ms instead of 1.8 for two W1 tasks)
                # and buffered by NumPy only where the ranges really overlap
                for channel in self.store:
                    channel[:held] = channel[self.start:self.start + held]
            self.start = 0
        self.store[:, self.start + held:self.start + held + task.size] = 0.0
        self.tasks.append(task)
        self.counts.append(TraceStats(samples=task.size))
        self.job = Job(self.job.units + task.units, task.width, task.samples_per_pixel)


def lowest_in_flight(next_slot: int, live: PathBatch, riding: ShadowBatch | None) -> int:
    """The lowest slot whose sample may still gain radiance: a live path's, a
    riding shadow ray's, or the next one to issue."""
    lowest = next_slot
    if len(live):
        lowest = min(lowest, int(live.slot.min()))
    if riding is not None and len(riding):
        lowest = min(lowest, int(riding.slot.min()))
    return lowest


def hand_over(stream: TaskStream, held: HeldTasks, next_slot: int, live: PathBatch, riding: ShadowBatch | None,
              take: bool = True) -> int:
    """Streaming, once a bounce: hand back the oldest tasks whose paths
    have all ended, and once every held sample is issued, take the next task
    into the same wavefront.

    Without this each task ended in a drain: its last few deep paths took
    ~20-40 more bounces of a few hundred rays each, where NumPy's fixed cost
    per call is the whole cost (~6 % of W1's time, ~3.5 % of the cover's).
    Now only the render's last tasks drain; the others' last paths ride along
    with the next task's first.  The held tasks share one run of slots,
    oldest first (:class:`HeldTasks`); a task is done when nothing in flight
    (a path, a shadow ray riding with the next query, a sample not yet
    issued) has a slot in its range.  Each sample's radiance is still the sum
    of its own path's terms in the same order, so the image is the same, bit
    for bit.  Returns the new ``next_slot``; ``live`` and ``riding`` have
    their slots moved down in place when tasks leave the front.
    """
    lowest = lowest_in_flight(next_slot, live, riding)
    done = 0
    while held.tasks and done + held.tasks[0].size <= lowest:
        size = held.tasks[0].size
        finished = held.radiance[:, :size]
        stream.finished(*held.pop(), radiance=finished)
        done += size
    if done:
        next_slot -= done
        live.slot -= done
        if riding is not None:
            riding.slot -= done
    if take and next_slot == held.job.size and len(held.tasks) < HELD_TASKS:
        new = stream.next_job(idle=not held.tasks)
        if new is not None:
            held.add(new)
    return next_slot


def refill(cs: CompiledScene, frame, sampler: Sampler, job: Job, live: PathBatch, next_slot: int, capacity: int,
           mis: bool = True):
    """Stage 1: free slots take camera rays of the job's next samples, once
    enough are free (so a long tail of a few deep paths never costs a
    near-empty NumPy call per bounce).  Returns the batch and the next slot."""
    free = capacity - len(live)
    if next_slot < job.size and (len(live) == 0 or free >= capacity * REFILL_FRACTION):
        stop = min(job.size, next_slot + free)
        live = camera_paths(cs, frame, sampler, job, next_slot, stop, before=live, mis=mis)
        next_slot = stop
    return live, next_slot


def intersect_with_shadows(cs: CompiledScene, live: PathBatch, shadows: ShadowBatch, radiance,
                           stats: TraceStats) -> Hits:
    """Stage 2 with the previous bounce's shadow rays (stage 6) in the same
    nearest-hit query: the paths' rays with no ``t_max``, the shadow rays
    with theirs.  The unblocked shadow rays (no hit before ``t_max``) add
    their contribution; returns the paths' hits, exactly those of a query
    of their own (every ray's hit is its own, whatever rays go with it)."""
    n = len(live)
    stats.shadow_rays += len(shadows)
    hits = cs.shapes.intersect(np.concatenate((live.origin, shadows.origin), axis=1),
                               np.concatenate((live.direction, shadows.direction), axis=1),
                               np.concatenate((np.full(n, np.inf, dtype=shadows.t_max.dtype), shadows.t_max)),
                               time=None if live.time is None else np.concatenate((live.time, shadows.time)))
    visible = true_rows(hits.primitive_idx[n:] < 0)
    scatter_add(radiance, gather(shadows.slot, visible), gather(shadows.contribution, visible))
    return Hits(hits.t[:n], hits.primitive_idx[:n])


def escaped(cs: CompiledScene, live: PathBatch, hits, radiance, groups: KernelGroups | None = None):
    """Stage 3: paths that hit nothing add ``throughput * background`` and
    end.  Returns the paths, what they hit, which of them escaped (None:
    none are left in the batch), and the runs of rows of each scatter kernel
    (None: the rows are not grouped).

    Where few escaped (at most ``ESCAPED_KEPT_FRACTION``: cornell_spheres'
    open front loses ~1 % a bounce) and one kernel serves most hits (the
    others less than ``GROUPED_OTHER_SHARE``) they stay in the batch until stage 9
    compacts it anyway, marked absorbed from the start, with a stand-in hit:
    primitive 0 at ``t = 0`` (the path's own vertex), its normals made the
    reversed ray (unit, facing it, front side) and its ``uv`` 0, so that
    every kernel computes finite numbers for it.  Every later stage skips
    absorbed rows or works row by row and drops them at the end (no random
    number depends on a row's position), so the image is the same, and one
    compaction of every field is saved per bounce.  Otherwise only the hit
    rows go on, grouped by the scatter kernel that serves them (given
    ``groups``): stage 7 then runs each kernel on a slice of the batch (no
    gathers or scatters, and no kernel over rows another one's results
    overwrite), and stage 7b finds the glass rows there.  No stage reads a
    path's position in the batch (see :func:`advance`).
    """
    esc_idx = true_rows(hits.primitive_idx < 0)
    t, primitive_idx = hits.t, hits.primitive_idx
    gone = runs = None
    if esc_idx.size:
        seen = gather(live.throughput, esc_idx)
        light = cs.scene.background.radiance_at(live.direction, esc_idx)
        if seen.dtype == np.result_type(seen, light):
            seen *= light  # throughput * background in the gathered array
        else:
            seen = seen * light
        scatter_add(radiance, gather(live.slot, esc_idx), seen)
        group = None if groups is None else groups.of(primitive_idx)
        if (cs.media is None and esc_idx.size <= ESCAPED_KEPT_FRACTION * len(live)
                and (group is None or not groups.mixed(group))):
            gone = primitive_idx < 0
            t, primitive_idx = t.copy(), primitive_idx.copy()
            t[esc_idx], primitive_idx[esc_idx] = 0, 0
        else:
            if group is None:
                hit_idx = true_rows(primitive_idx >= 0)
            else:
                hit_idx, runs = groups.order(group)
            live, t, primitive_idx = live.take(hit_idx), gather(t, hit_idx), gather(primitive_idx, hit_idx)
    if len(live) == 0:
        return live, None, None, None
    surface = cs.shapes.surface(live.origin, live.direction, t, primitive_idx, uv=cs.materials.needs_uv, time=live.time)
    if gone is not None:  # the stand-ins' normals: their own rays reversed (surface's arrays are its own)
        facing = -gather(live.direction, esc_idx)
        scatter(surface.normal, esc_idx, facing)
        if surface.geometric_normal is not surface.normal:
            scatter(surface.geometric_normal, esc_idx, facing)
        surface.front_face[esc_idx] = True
        if surface.uv is not None:
            surface.uv[:, esc_idx] = 0
    return live, surface, gone, runs


@dataclass(slots=True)
class DrawnUniforms:
    """A bounce's uniforms, drawn ahead for every path of a small batch (see
    :func:`draw_together`); the stages take their rows' columns."""

    bounce: np.ndarray  # (2, N) at the render's precision: the material's sample
    light_point: np.ndarray | None  # (2, N) float64: the point on the light (None: no light sampling)
    light_choice: np.ndarray | None  # (2, N) float64: which light (first), roulette (second); None: neither


def draw_together(cs: CompiledScene, sampler: Sampler, live: PathBatch, emitters, roulette) -> DrawnUniforms | None:
    """Every uniform a bounce of at most ``TOGETHER_PATHS`` paths may draw
    (None for a bigger one: each stage draws its own rows' then).

    The tail after roulette is ~20 bounces of a few hundred paths or fewer,
    where a draw costs what its ~40 NumPy calls cost whatever the paths: the
    three pairs in one call (:meth:`Sampler.pairs_together`), each path's
    numbers the same as drawn separately, bit for bit.  Pairs a stage then
    does not read (a specular vertex's light point, roulette's before its
    depth) cost a few columns of that one call."""
    if len(live) > TOGETHER_PATHS:
        return None
    depth = live.depth
    pairs, dtypes = [bounce_dimension(depth)], [cs.dtype]
    if emitters is not None:
        pairs.append(light_point_dimension(depth))
        dtypes.append(np.float64)
    choice = roulette is not None or (emitters is not None and len(emitters) > 1)
    if choice:
        pairs.append(light_choice_dimension(depth))
        dtypes.append(np.float64)
    u = sampler.pairs_together(live.state, pairs, dtypes)
    return DrawnUniforms(bounce=u[0], light_point=u[1] if emitters is not None else None,
                         light_choice=u[-1] if choice else None)


def surface_albedo(cs: CompiledScene, surface):
    """The hits' textured albedo ``(3, N)`` (one texture evaluation per
    bounce, shared by light sampling and scattering), or None when no albedo
    is textured (the kernels then gather the table's colours, as always)."""
    table = cs.materials
    if table.textures is None or not (table.albedo_texture >= 0).any():
        return None
    return table.albedo_at(surface.material_idx, surface.point, surface.uv)


def emitted(cs: CompiledScene, live: PathBatch, surface, radiance, emitters=None, gone=None, kind=None) -> np.ndarray:
    """Stage 4: paths that hit an emitter end there, adding ``throughput *
    color`` if they struck its front side (emission is one-sided, as in RTOW
    book 3, pbrt and Mitsuba: a sphere emits outwards, a quad or triangle on
    its ``cross(u, v)`` / ``cross(v1 - v0, v2 - v0)`` side).  With light
    sampling (``emitters`` given) a hit found by a diffuse bounce is weighted
    by the power heuristic against the light sample that could have found it.
    Returns the ``absorbed`` mask the later stages extend (``gone``, the
    paths that escaped but stay in the batch, are in it from the start and
    emit nothing: their hit is a stand-in).  ``kind``: the hits' material
    kinds, if taken already."""
    table = cs.materials
    absorbed = np.zeros(len(live), dtype=bool) if gone is None else gone.copy()
    emissive = table.code("emissive")
    if not (table.kind == emissive).any():
        return absorbed
    on_emitter = (gather(table.kind, surface.material_idx) if kind is None else kind) == emissive
    if gone is not None:
        on_emitter &= ~gone
    sel = true_rows(on_emitter)
    if sel.size:
        absorbed[sel] = True
        sel = sel[gather(surface.front_face, sel)]
        m = gather(surface.material_idx, sel)
        if table.textures is None:
            color = gather(table.emission, m)
        else:
            color = table.emission_at(m, gather(surface.point, sel), None if surface.uv is None else gather(surface.uv, sel))
        value = gather(live.throughput, sel) * color
        if emitters is not None:
            value *= emission_weight(emitters, live, surface, sel)
        scatter_add(radiance, gather(live.slot, sel), value)
    return absorbed


def mis_weight(pdf_a, pdf_b):
    """The power heuristic (Veach 1997, 9.2.3, beta = 2): the weight of a
    sample drawn with density ``pdf_a`` when ``pdf_b`` could also have drawn it."""
    a2 = pdf_a * pdf_a
    with np.errstate(invalid="ignore", divide="ignore"):
        w = a2 + pdf_b * pdf_b
        np.divide(a2, w, out=w)
    positive = a2 > 0
    return w if positive.all() else np.where(positive, w, 0.0)  # a light sample's pdf is positive: no where


def emission_weight(emitters, live: PathBatch, surface, sel) -> np.ndarray:
    """MIS weights ``(N,)`` of emission hits ``sel`` found by the material's
    sampling: 1 after a delta vertex (or the camera), else the power heuristic
    of the material's pdf against the light sample's (from the previous vertex,
    which is the ray's origin)."""
    weight = np.ones(sel.size)
    e = gather(emitters.emitter_of, gather(surface.primitive_idx, sel))
    # a black emitter is not in the table (e = -1): it adds nothing, at any weight
    diffuse = true_rows(~gather(live.specular, sel) & (e >= 0))
    if diffuse.size:
        rows = gather(sel, diffuse)
        e = gather(e, diffuse)
        p_light = emitters.pdf(e, gather(live.origin, rows), gather(surface.point, rows),
                               None if live.time is None else gather(live.time, rows))
        weight[diffuse] = mis_weight(gather(live.bsdf_pdf, rows), p_light)
    return weight


def diffuse_rows(cs: CompiledScene, surface) -> np.ndarray:
    """Hits whose material is sampled with a density (lambertian, and phong
    as lambertian): the vertices next-event estimation serves."""
    # decided per material (a handful of rows), then gathered per hit: np.isin
    # over the hits cost ~0.1 ms a bounce, nearly all of it fixed, a tenth of
    # each of the tail's near-empty bounces
    return diffuse_materials(cs.materials).take(surface.material_idx)


def diffuse_materials(table) -> np.ndarray:
    """``(K,)`` bool: the table's materials sampled with a density (see :func:`diffuse_rows`)."""
    return (table.kind == table.code("lambertian")) | (table.kind == table.code("phong"))


def sample_lights(cs: CompiledScene, sampler: Sampler, emitters, live: PathBatch, surface, diffuse, absorbed,
                  max_depth: int, albedo=None, drawn: DrawnUniforms | None = None) -> ShadowBatch:
    """Stage 5: one light sample per diffuse vertex, as a shadow ray.

    Only paths allowed another segment take one (the shadow ray is that
    segment), so light sampling and material sampling see paths of the same
    lengths.  The contribution is
    ``throughput * albedo / pi * cos * radiance * w_light / p_light``.
    """
    rows = true_rows(diffuse & ~absorbed & (live.depth + 1 < max_depth))
    u_point, u_choice = light_uniforms(sampler, emitters, live, rows, drawn)
    time = None if live.time is None else gather(live.time, rows)
    light = emitters.sample(gather(surface.point, rows), u_choice, u_point, time)
    normal = gather(surface.normal, rows)
    p_material = lambertian_pdf(normal, light.direction)
    carries = light.carries if light.carries is not None else light.radiance.max(axis=0) > 0.0
    ok = true_rows((p_material > 0.0) & carries)
    rows, pdf, p_material = gather(rows, ok), gather(light.pdf, ok), gather(p_material, ok)
    albedo = gather(cs.materials.albedo, gather(surface.material_idx, rows)) if albedo is None else gather(albedo, rows)
    f_cos = albedo * p_material  # lambertian_eval's value: its pdf is the one just taken
    if len(emitters) == 1 and emitters.texture is None:
        # one untextured emitter: every sample that carries light has its
        # column times True, the column itself, which broadcasts (no gather)
        radiance = emitters.radiance[:, :1]
    else:
        radiance = gather(light.radiance, ok)
    # the product in place, left to right as written: throughput f_cos radiance (w_light / p_light)
    contribution = gather(live.throughput, rows) * f_cos
    contribution *= radiance
    weight = mis_weight(pdf, p_material)
    weight /= pdf
    contribution *= weight
    return ShadowBatch(origin=gather(surface.point, rows), direction=gather(light.direction, ok).astype(cs.dtype, copy=False),
                       t_max=(gather(light.distance, ok) * (1.0 - SHADOW_EPSILON)).astype(cs.dtype, copy=False),
                       contribution=contribution, slot=gather(live.slot, rows),
                       time=None if time is None else gather(time, ok),
                       media_mask=None if live.media_mask is None else gather(live.media_mask, rows))


def light_uniforms(sampler: Sampler, emitters, live: PathBatch, rows, drawn: DrawnUniforms | None = None):
    """The uniforms of the light samples of paths ``rows``: the point on the
    emitter ``(2, R)``, and those choosing the emitter, or None with one
    emitter (nothing to choose: not drawing the pair changes no other number,
    as a pinhole camera's lens pair); the rows' columns of ``drawn``'s if
    given.  The rows' states are gathered here and dropped on return: light
    sampling holds the most memory of any stage, and a fresh worker faults
    in every page of its peak."""
    if drawn is not None:
        return gather(drawn.light_point, rows), None if len(emitters) == 1 else gather(drawn.light_choice[0], rows)
    state, depth = gather(live.state, rows), gather(live.depth, rows)
    u_point = sampler.pairs(state, light_point_dimension(depth))
    if len(emitters) == 1:
        return u_point, None
    return u_point, sampler.uniform(state, light_choice_dimension(depth), 0)


def trace_shadow_rays(cs: CompiledScene, shadows: ShadowBatch, radiance, stats: TraceStats) -> None:
    """Stage 6: the any-hit query for every shadow ray; the unblocked add their
    contribution (with media, times the transmittance along the way)."""
    if len(shadows) == 0:
        return
    stats.shadow_rays += len(shadows)
    visible = true_rows(~cs.shapes.occluded(shadows.origin, shadows.direction, shadows.t_max, shadows.time))
    contribution = gather(shadows.contribution, visible)
    if shadows.media_mask is not None:
        contribution *= shadow_transmittance(cs, gather(shadows.origin, visible), gather(shadows.direction, visible),
                                             gather(shadows.t_max, visible), gather(shadows.media_mask, visible))
    scatter_add(radiance, gather(shadows.slot, visible), contribution)


def scatter_hits(cs: CompiledScene, sampler: Sampler, kernels, live: PathBatch, surface, absorbed, albedo=None,
                 drawn: DrawnUniforms | None = None, kind=None, runs=None):
    """Stage 7: hits are routed by material kind, one kernel per kind present;
    throughput is multiplied by the attenuation (``albedo (3, N)``: the hits'
    textured albedo, if any; ``drawn``: the uniforms, and ``kind``, the
    hits' material kinds, if taken already; ``runs``: each kernel's rows,
    ``(start, stop)``, if stage 3 grouped them).  Returns the new directions
    and the ``absorbed`` mask."""
    table = cs.materials
    material, normal, front_face = surface.material_idx, surface.normal, surface.front_face
    if runs is not None:
        return _scatter_runs(cs, sampler, kernels, live, surface, absorbed, albedo, drawn, runs)
    u = drawn.bounce if drawn is not None else sampler.pairs(live.state, bounce_dimension(live.depth), cs.dtype)
    if len(kernels) == 1 and not (table.kind == table.code("emissive")).any():
        # a lone kind and no emitters: no routing, no gathers (absorbed holds
        # only the escaped paths left in the batch, if any)
        att, direction, dead = kernels[0][1](table, material, live.direction, normal, front_face, u, albedo)
        live.throughput *= att
        return direction, dead | absorbed
    if kind is None:
        kind = gather(table.kind, material)
    routes = [(true_rows(gather(np.isin(table.kind, codes), material) if len(codes) > 1 else kind == codes[0]), kernel)
              for codes, kernel in kernels]
    routes = [(sel, kernel) for sel, kernel in routes if sel.size]
    if albedo is None and routes:
        # The kind with the most hits (the walls' lambertian) runs over every
        # row, so its rows need no gathers and scatters; the other kinds'
        # rows are then overwritten by index.  Kernels are elementwise, so
        # every routed row gets exactly its own kernel's numbers; rows of no
        # kernel (emitters) got the main kernel's but are absorbed already.
        main = max(range(len(routes)), key=lambda k: routes[k][0].size)
        att, direction, dead = routes[main][1](table, material, live.direction, normal, front_face, u)
        for k, (sel, kernel) in enumerate(routes):
            if k != main:
                a, d, dd = kernel(table, gather(material, sel), gather(live.direction, sel), gather(normal, sel),
                                  gather(front_face, sel), gather(u, sel))
                scatter(att, sel, a)
                scatter(direction, sel, d)
                dead[sel] = dd
        live.throughput *= att
        return direction, absorbed | dead
    direction = live.direction  # overwritten row by row below
    for sel, kernel in routes:
        att, d, dead = kernel(table, gather(material, sel), gather(live.direction, sel), gather(normal, sel),
                              gather(front_face, sel), gather(u, sel), None if albedo is None else gather(albedo, sel))
        scatter(live.throughput, sel, gather(live.throughput, sel) * att)
        scatter(direction, sel, d)
        absorbed[sel] = dead | gather(absorbed, sel)  # an escaped path left in the batch stays absorbed
    return direction, absorbed


def _scatter_runs(cs: CompiledScene, sampler: Sampler, kernels, live: PathBatch, surface, absorbed, albedo,
                  drawn: DrawnUniforms | None, runs):
    """:func:`scatter_hits` of rows grouped by kernel (``runs``: each
    kernel's ``(start, stop)``): each kernel on its slice of the batch, no
    gathers or scatters (rows of no kernel, emitters, are absorbed and keep
    theirs).

    Where every metal is a perfect mirror (no fuzz), the bounce's uniforms
    are drawn for the rows before the mirrors' run only (``_KERNELS`` puts
    metal last): a mirror without fuzz reads none but for the rare rows
    whose reflection has a zero component, which it draws by itself
    (:class:`~wavefront.materials.LazyUniforms`).  Every path's
    numbers are its state's and pair's, whichever rows are drawn together:
    the same image.  W1's bounces are 2-55 % mirror hits."""
    table = cs.materials
    material, normal, front_face = surface.material_idx, surface.normal, surface.front_face
    direction = live.direction  # overwritten run by run
    # with some fuzz (the cover's metals) every metal row reads its pair: drawn up front with the others'
    lazy = _metal if not table.fuzz.any() else None
    drawn_stop = max((start if kernel is lazy else stop for (start, stop), (_, kernel) in zip(runs, kernels)),
                     default=0)
    if drawn is not None:
        u = drawn.bounce
    elif drawn_stop:
        u = sampler.pairs(live.state[:drawn_stop], bounce_dimension(live.depth[:drawn_stop]), cs.dtype)
    for (start, stop), (_, kernel) in zip(runs, kernels):
        if stop > start:
            run = slice(start, stop)
            d = direction[:, run]
            if stop <= drawn_stop or drawn is not None:
                u_run = u[:, run]
            else:  # the mirrors' run: drawn as the kernel asks
                u_run = LazyUniforms(_draw_bounce(sampler, live.state[run], live.depth[run], cs.dtype), cs.dtype)
            # the new directions straight into the batch's (no (3, n) copy)
            att, _, dead = kernel(table, material[run], d, normal[:, run], front_face[run],
                                  u_run, None if albedo is None else albedo[:, run], out=d)
            if kernel is not _dielectric:  # glass attenuates by 1: x * 1 = x exactly, not multiplied
                live.throughput[:, run] *= att
            if kernel is _metal:  # the others absorb nothing
                absorbed[run] |= dead
    return direction, absorbed


def _draw_bounce(sampler: Sampler, state, depth, dtype):
    """The bounce pairs ``(2, R)`` of paths ``state``, ``depth`` at rows
    ``rows`` (indices; None: every row), as :meth:`Sampler.pairs` draws them."""
    def draw(rows=None):
        if rows is None:
            return sampler.pairs(state, bounce_dimension(depth), dtype)
        return sampler.pairs(gather(state, rows), bounce_dimension(gather(depth, rows)), dtype)
    return draw


def record_sampling(cs: CompiledScene, live: PathBatch, surface, diffuse, direction, kind=None,
                    glass_run: tuple[int, int] | None = None) -> None:
    """After scattering: what the next vertex's MIS weight and roulette need.

    Lambertian rows sampled ``cos / pi`` (taken about the same shading
    normal the kernel used); every other kind is a delta, whose ``bsdf_pdf``
    is never read.  Refraction multiplies ``eta^2`` by the squared relative
    index crossed (``kind``: the hits' material kinds, if taken already;
    ``glass_run``: the glass rows' ``(start, stop)``, if stage 3 grouped them).
    ``diffuse`` None: the paths carry no MIS fields (see :func:`camera_paths`),
    and only ``eta_scale`` is kept up.
    """
    table = cs.materials
    if diffuse is not None:
        live.specular = ~diffuse
        # float64 whatever the render's precision (lambertian_pdf's type): a
        # batch's field must not change type with its refill history, or MIS
        # arithmetic (and the image) would depend on the chunk size.  Every
        # row's, specular or not: emission_weight reads it only after a
        # diffuse vertex, and a where zeroing the others cost ~50 us of a 32
        # Ki path bounce (its random mask mispredicts), ~0.5 % of the bounce.
        live.bsdf_pdf = lambertian_pdf(surface.normal, direction)
    if glass_run is not None:
        # a transmitted direction leaves on the far side of the (ray-facing) normal
        start, stop = glass_run
        if stop == start:  # no glass hits (or no glass in the scene)
            return
        through = true_rows(dot(surface.normal[:, start:stop], direction[:, start:stop]) < 0.0)
        through += start
        if through.size:
            index = gather(table.refraction_index, gather(surface.material_idx, through)).astype(np.float64)
            eta = np.where(gather(surface.front_face, through), index, 1.0 / index)  # n_transmitted / n_incident
            live.eta_scale[through] *= eta * eta
        return
    if kind is None:
        kind = gather(table.kind, surface.material_idx)
    glass = true_rows(kind == table.code("dielectric"))
    if glass.size:
        # a transmitted direction leaves on the far side of the (ray-facing) normal
        through = gather(glass, true_rows(dot(gather(surface.normal, glass), gather(direction, glass)) < 0.0))
        index = gather(table.refraction_index, gather(surface.material_idx, through)).astype(np.float64)
        eta = np.where(gather(surface.front_face, through), index, 1.0 / index)  # n_transmitted / n_incident
        live.eta_scale[through] *= eta * eta


def russian_roulette(sampler: Sampler, live: PathBatch, absorbed, start_depth: int,
                     drawn: DrawnUniforms | None = None) -> np.ndarray:
    """Stage 8: paths that have traced at least ``start_depth`` segments go on
    with probability ``q = min(max(throughput) * eta^2, 0.95)`` and divide
    their throughput by ``q``; the others end (``drawn``: the uniforms, if
    drawn already).  Returns ``absorbed``."""
    if drawn is not None:
        return _roulette_drawn(live, absorbed, start_depth, drawn)
    rows = true_rows(~absorbed & (live.depth + 1 >= start_depth))
    if rows.size == 0:
        return absorbed
    if rows.size <= ROULETTE_GATHERED * len(live):
        return _roulette_gathered(sampler, live, absorbed, rows)
    # every row's survival (no gathers of the throughput), the rows' read
    survival = _max_reduce(live.throughput, axis=0) * live.eta_scale
    np.minimum(survival, ROULETTE_MAX_SURVIVAL, out=survival)
    u = sampler.uniform(gather(live.state, rows), light_choice_dimension(gather(live.depth, rows)), 1)
    survive = u < gather(survival, rows)
    absorbed[rows] = ~survive  # every row was still alive: only the ended become True
    # the survivors' throughput divided by their survival over the whole
    # batch, the others' by 1.0 (exact): no gather and scatter of the
    # survivors' columns; in float64, rounded once to the throughput's type
    # as the scatter of the quotient was
    kept = gather(rows, true_rows(survive))
    divisor = np.ones(len(live))
    divisor[kept] = gather(survival, kept)
    live.throughput /= divisor
    return absorbed


# Roulette works on the rows it applies to, gathered, where they are at most
# this fraction of the batch (see _roulette_gathered); above it, over the
# whole batch.  W1's bounces mix new paths with a few deep ones (0-25 % of a
# bounce past the roulette depth, until the last task drains).  Measured on
# 60 Ki float32 paths: 10 % of them 102 us against 314 over the whole batch,
# 25 % 194 against 343, 40 % 298 against 357, even at 50 %, 485 against 398
# at 70 % (the whole batch's float64 division is most of its time).
ROULETTE_GATHERED = 0.4


def _roulette_gathered(sampler: Sampler, live: PathBatch, absorbed, rows) -> np.ndarray:
    """:func:`russian_roulette` of the paths ``rows`` (indices), on their
    gathered columns: the same operations row by row (the column's maximum
    times ``eta^2`` in float64, capped, compared with the uniform, and the
    survivors' throughput divided by it in float64, rounded once to its
    type); the other rows, divided by 1.0 over the whole batch, are left
    as they are (exactly what that division gives)."""
    throughput = gather(live.throughput, rows)
    survival = _max_reduce(throughput, axis=0) * gather(live.eta_scale, rows)
    np.minimum(survival, ROULETTE_MAX_SURVIVAL, out=survival)
    u = sampler.uniform(gather(live.state, rows), light_choice_dimension(gather(live.depth, rows)), 1)
    survive = u < survival
    absorbed[rows] = ~survive  # every row was still alive: only the ended become True
    kept = true_rows(survive)
    scatter(live.throughput, gather(rows, kept), gather(throughput, kept) / gather(survival, kept))
    return absorbed


def _roulette_drawn(live: PathBatch, absorbed, start_depth: int, drawn: DrawnUniforms) -> np.ndarray:
    """:func:`russian_roulette` of a small batch whose uniforms are drawn:
    every row's survival worked out and the survivors' throughput divided by
    it over the whole batch (the others' by 1.0, exact), ~14 NumPy calls
    where gathering the rows and scattering the survivors back took ~24, a
    bounce's fixed cost in the tail.  Row by row the same operations: the
    column's maximum times ``eta^2`` (in float64), capped, compared with the
    uniform, and the throughput divided by it in float64 and rounded once to
    its type (as the scatter of the quotient did)."""
    applies = ~absorbed
    applies &= live.depth >= start_depth - 1  # depth + 1 >= start_depth (small ints)
    if not applies.any():
        return absorbed
    survival = _max_reduce(live.throughput, axis=0) * live.eta_scale
    np.minimum(survival, ROULETTE_MAX_SURVIVAL, out=survival)
    survive = drawn.light_choice[1] < survival
    absorbed |= applies & ~survive  # every such row was still alive: only the ended become True
    survive &= applies
    live.throughput /= np.where(survive, survival, 1.0)
    return absorbed


_max_reduce = np.maximum.reduce


def advance(live: PathBatch, surface, direction, absorbed, max_depth: int) -> PathBatch:
    """Stage 9: paths continue from their hit points; absorbed paths end, and
    so do paths that have used ``max_depth`` segments (they contribute
    nothing more); the survivors are compacted."""
    live.origin = surface.point
    live.direction = direction
    live.depth += 1
    alive = ~absorbed & (live.depth < max_depth)
    ended = alive.size - np.count_nonzero(alive)
    if ended == 0:
        return live
    if ended > FILLED_FRACTION * alive.size:
        return live.take(true_rows(alive))
    # Few ended (cornell_spheres' bounces before roulette lose ~1.3 % of
    # their paths): the last paths move into their rows instead, a copy of a
    # few rows where compacting every field (~85 bytes a path) cost 0.35 ms of
    # each 32 Ki path bounce.  No stage reads a path's position in the
    # batch (its numbers come from its state, its radiance goes to its slot,
    # and no slot has two rows), so the order changes no pixel.
    size = alive.size - ended
    return live.fill(true_rows(~alive[:size]), true_rows(alive[size:]) + size, size)


# -- participating media (wavefront.media) ----------------------------------------

def walk_boundaries(media, origin, direction, t_end, mask, visit, first: Hits | None = None) -> np.ndarray:
    """Visit the pieces of the segments ``origin + t direction``, ``0 <= t <
    t_end``, between the invisible media boundaries they cross, in order.

    For each piece, ``visit(row, start, stop, medium, piece)`` gets the rows
    (indices into the segments) still walking, where their current pieces
    start and stop along the segments, the medium each is in and the piece's
    number (boundaries crossed so far), and returns which of those rows end
    there (a path that scattered).  Every other row whose piece ended on a
    boundary crosses it (its bit in ``mask``, updated in place, is set on
    entering and cleared on leaving) and goes on.  Distances are measured from
    ``origin``: a path's hit was found from its vertex, and a restart on a
    boundary only looks for the next boundary.  Returns the rows that would
    cross more than ``CROSSINGS_PER_SEGMENT - 1`` boundaries (unvisited past
    that: rounding trouble, not light).  The first piece's search
    starts ``FIRST_BACKOFF`` behind ``origin``.  ``first``, if given, is the
    first piece's boundary query already made without a ``t_max`` (see
    :func:`first_boundaries`); its hits at or past the piece's end are not
    crossings, exactly as the query with that ``t_max`` would not return them.
    """
    row = np.arange(t_end.shape[0])
    start = np.zeros(row.size, dtype=np.float64)
    for piece in range(CROSSINGS_PER_SEGMENT):
        end = t_end.take(row).astype(np.float64)
        d = gather(direction, row)
        # the boundary query starts just before the piece (see RESTART_BACKOFF),
        # so that a boundary right past a crossing, or past a vertex in a
        # medium, is not skipped as T_MIN skips surfaces at a ray's origin
        back = start - (RESTART_BACKOFF if piece else FIRST_BACKOFF)
        o = gather(origin, row) + back.astype(d.dtype) * d
        if media.boundaries is not None:
            t_max = (end - back - COINCIDENT).astype(o.dtype)
            if piece == 0 and first is not None:
                hits = first
                crossing = (hits.primitive_idx >= 0) & (hits.t < t_max)
            else:
                hits = boundary_hits(media, o, d, t_max)
                crossing = hits.primitive_idx >= 0
            stop = np.where(crossing, np.maximum(back + hits.t, start), end)  # one behind the origin: at it
        else:
            crossing, stop = np.zeros(row.size, dtype=bool), end
        # No closed boundary reaches infinity: a piece that does is in no
        # medium, whatever a crossing missed by rounding left in the mask.
        unbounded = row.take(true_rows(stop == np.inf))
        mask[unbounded] = 0
        ended = visit(row, start, stop, current_medium(mask.take(row)), piece)
        go = true_rows(crossing & ~ended)
        if go.size == 0:
            return np.zeros(0, dtype=np.int64)
        surface = media.boundaries.surface(gather(o, go), gather(d, go), hits.t.take(go), hits.primitive_idx.take(go))
        row, start = row.take(go), stop.take(go)
        mask[row] = cross(mask.take(row), surface.material_idx, surface.front_face)  # a boundary's material: its medium
    return row


def boundary_hits(media, origin, direction, t_max) -> Hits:
    """The nearest boundary hit of each ray before ``t_max``, asking the
    boundaries' intersector only about rays whose segment meets the box
    around every boundary (a slab test, padded; rays that pass it get the
    intersector's exact answer, so the cull changes no hit)."""
    n = origin.shape[1]
    lo, hi = media.bounds
    with np.errstate(divide="ignore", invalid="ignore"):
        inverse = 1.0 / direction.astype(np.float64)
        t1 = (lo - origin) * inverse
        t2 = (hi - origin) * inverse
        # fmin/fmax skip the NaN of a ray lying in a slab's plane: that axis then culls nothing
        near = np.fmax.reduce(np.fmin(t1, t2), axis=0)
        far = np.fmin.reduce(np.fmax(t1, t2), axis=0)
    meets = ~((near > far) | (far < 0.0) | (near > t_max))  # NaN comparisons are false: such rays are kept
    if meets.all():
        return media.boundaries.intersect(origin, direction, t_max)
    t = np.full(n, np.inf, dtype=origin.dtype)
    primitive = np.full(n, -1, dtype=np.int32)
    idx = true_rows(meets)
    if idx.size:
        hits = media.boundaries.intersect(gather(origin, idx), gather(direction, idx),
                                          np.broadcast_to(t_max, (n,)).take(idx))
        t[idx], primitive[idx] = hits.t, hits.primitive_idx
    return Hits(t, primitive)


def first_boundaries(media, origin, direction) -> Hits:
    """The first piece's boundary query of :func:`walk_boundaries` (from
    the same backed-off origins, bit for bit) with no ``t_max``."""
    back = np.full(origin.shape[1], -FIRST_BACKOFF)  # the walk's start (0) less the first piece's back-off
    o = origin + back.astype(direction.dtype) * direction
    return boundary_hits(media, o, direction, np.full(origin.shape[1], np.inf, dtype=o.dtype))


def intersect_in_media(cs: CompiledScene, sampler: Sampler, live: PathBatch):
    """Stage 2 in a scene with media: the paths' hits, asking the
    intersector no further than needed (fewer BVH nodes to walk).

    A path in a medium draws its first free flight ``t0`` (the first piece's
    number, as :func:`travel_media` will) before its hit is known.  Where the
    first boundary along the ray lies beyond ``t0`` (so the walk's first piece
    reaches ``t0`` whatever the hit), the hit only matters if it is nearer
    than ``t0``: the query stops at a cap just past ``t0``.  A hit found
    there is the hit (the nearest), bit for bit; a path that finds none
    scatters at ``t0`` in the walk, as it would have, and its ``t`` is set to
    the cap (a finite end, nearer than any hit, so the walk's first piece
    ends past ``t0``).  In dense fog (the blue ball of RTOW's final scene)
    most paths scatter within a few units: their queries prune most of the
    tree.  Returns (hits, the first piece's boundary hits for the walk, or
    None when the scene's media have no invisible boundaries).
    """
    media = cs.media
    if media.boundaries is None:
        return cs.shapes.intersect(live.origin, live.direction, time=live.time), None
    first = first_boundaries(media, live.origin, live.direction)
    medium = current_medium(live.media_mask)
    rows = true_rows((medium >= 0) & (first.primitive_idx >= 0))
    if rows.size == 0:
        return cs.shapes.intersect(live.origin, live.direction, time=live.time), first
    u = sampler.uniform(live.state.take(rows), medium_dimension(live.depth.take(rows), 0), 0)
    with np.errstate(divide="ignore", invalid="ignore"):
        t0 = -np.log1p(-u) / media.density.take(medium.take(rows))
        # the cap: past t0 by far more than rounding to the render's precision
        cap = (t0 + (FLIGHT_CAP_SLACK * t0 + T_MIN)).astype(cs.dtype)
        # the first piece ends at the boundary (the walk's start less its back-off, plus t) or the hit
        capped = (cap < np.inf) & (first.t.take(rows) - FIRST_BACKOFF > cap.astype(np.float64))
    rows, cap = rows.take(true_rows(capped)), cap.take(true_rows(capped))
    t_max = np.full(len(live), np.inf, dtype=cs.dtype)
    t_max[rows] = cap
    hits = cs.shapes.intersect(live.origin, live.direction, t_max, time=live.time)
    missed = true_rows(hits.primitive_idx.take(rows) < 0)
    if missed.size:
        t = hits.t.copy()
        t[rows.take(missed)] = cap.take(missed)
        hits = Hits(t, hits.primitive_idx)
    return hits, first


def travel_media(cs: CompiledScene, sampler: Sampler, live: PathBatch, hits, first: Hits | None = None):
    """Stage 2b (scenes with media): free flight between each path's vertex
    and its hit.

    In every piece of the segment inside a medium, the path draws the
    distance to its next interaction, ``-ln(1 - u) / density`` (analog
    sampling: the probability of flying past a distance is the
    transmittance, so neither outcome reweights the throughput, and light
    reached through the medium needs no transmittance factor).  If that falls
    within the piece, the path scatters in the medium there; else it crosses
    the boundary ending the piece (its media mask changes) or reaches its
    hit.  Crossings spend no segment of ``max_depth``; a path that would make
    more than ``CROSSINGS_PER_SEGMENT - 1`` ends (it contributes nothing more).

    Returns
    -------
    (paths that reach their hit or escape, their hits, paths that scatter in
    a medium, the points ``(3, K)`` where they do)
    """
    media = cs.media
    n = len(live)
    t_scatter = np.full(n, np.inf)

    def free_flight(row, start, stop, medium, piece):
        ended = np.zeros(row.size, dtype=bool)
        inside = true_rows(medium >= 0)
        if inside.size:
            rows = row.take(inside)
            u = sampler.uniform(live.state.take(rows), medium_dimension(live.depth.take(rows), piece), 0)
            with np.errstate(divide="ignore"):  # density 0: an infinite flight, as if the medium were not there
                t = start.take(inside) - np.log1p(-u) / media.density.take(medium.take(inside))
            near = true_rows(t < stop.take(inside))
            t_scatter[rows.take(near)] = t.take(near)
            ended[inside.take(near)] = True
        return ended

    mask = live.media_mask.copy()
    lost = walk_boundaries(media, live.origin, live.direction, hits.t, mask, free_flight, first)
    live.media_mask = mask
    scatters = t_scatter < np.inf
    in_idx = true_rows(scatters)
    in_medium = live.take(in_idx)
    point = in_medium.origin + t_scatter.take(in_idx).astype(cs.dtype) * in_medium.direction
    keep = ~scatters
    keep[lost] = False
    if not keep.all():
        rest = true_rows(keep)
        live, hits = live.take(rest), Hits(hits.t.take(rest), hits.primitive_idx.take(rest))
    return live, hits, in_medium, point


def shadow_transmittance(cs: CompiledScene, origin, direction, t_max, mask) -> np.ndarray:
    """``(S,)`` fraction of light that crosses the media along unoccluded
    shadow rays: the product of ``exp(-density * length)`` over the pieces
    between boundaries (0 for a ray with more crossings than allowed)."""
    fraction = np.ones(t_max.shape[0])

    def attenuate(row, start, stop, medium, piece):
        inside = true_rows(medium >= 0)
        fraction[row.take(inside)] *= transmittance(cs.media.density.take(medium.take(inside)),
                                                    stop.take(inside) - start.take(inside))
        return np.zeros(row.size, dtype=bool)

    fraction[walk_boundaries(cs.media, origin, direction, t_max, mask.copy(), attenuate)] = 0.0
    return fraction


def scatter_in_media(cs: CompiledScene, sampler: Sampler, live: PathBatch, point,
                     emitters) -> tuple[PathBatch, ShadowBatch | None]:
    """Stages 5-9 for vertices in media: a light sample (its shadow ray
    attenuated by transmittance), then the isotropic phase function's sample
    (uniform on the sphere, pdf ``1 / (4 pi)``, so the throughput is
    multiplied by the albedo alone), roulette, and the next segment.  A black
    medium (albedo 0) is a pure absorber: its paths end here.  Returns the
    paths that go on and the light samples' shadow rays (None without light
    sampling), which the caller traces with the surfaces' (stage 6)."""
    settings = cs.scene.render
    albedo = medium_albedo(cs.media, current_medium(live.media_mask), point)
    absorbed = albedo.max(axis=0) <= 0.0
    shadows = None
    if emitters is not None:
        shadows = sample_lights_in_media(cs, sampler, emitters, live, point, albedo, absorbed, settings.depth)
    u = sampler.pairs(live.state, bounce_dimension(live.depth), cs.dtype)
    direction = random_unit_vector(u[0], u[1])
    live.throughput *= albedo
    if live.bsdf_pdf is not None:  # the MIS fields, where the paths carry them (see camera_paths)
        live.bsdf_pdf = np.full(len(live), ISOTROPIC_PDF)
        live.specular = np.zeros(len(live), dtype=bool)
    if settings.russian_roulette is not None:
        absorbed = russian_roulette(sampler, live, absorbed, settings.russian_roulette.depth)
    live.origin = point
    live.direction = direction
    live.depth += 1
    alive = ~absorbed & (live.depth < settings.depth)
    return (live if alive.all() else live.take(true_rows(alive))), shadows


def sample_lights_in_media(cs: CompiledScene, sampler: Sampler, emitters, live: PathBatch, point, albedo, absorbed,
                           max_depth: int) -> ShadowBatch:
    """One light sample per medium vertex, as :func:`sample_lights` does for
    surfaces, with the isotropic phase function ``1 / (4 pi)`` as both the
    scattering function and the pdf MIS weighs it against.  The contribution
    is ``throughput * albedo / (4 pi) * radiance * w_light / p_light`` (the
    transmittance comes with the shadow ray)."""
    rows = true_rows(~absorbed & (live.depth + 1 < max_depth))
    u_point, u_choice = light_uniforms(sampler, emitters, live, rows)
    origin = gather(point, rows)
    time = None if live.time is None else live.time.take(rows)
    light = emitters.sample(origin, u_choice, u_point, time)
    direction = light.direction.astype(cs.dtype)
    t_max = (light.distance * (1.0 - SHADOW_EPSILON)).astype(cs.dtype)
    ok = light.radiance.max(axis=0) > 0.0
    if cs.media.sealed is not None:
        # fog in a glass ball: its light samples outside the ball are blocked by the glass
        ok &= ~sealed_in(cs.media.sealed, current_medium(live.media_mask.take(rows)), origin, direction, t_max)
    ok = true_rows(ok)
    rows, pdf = rows.take(ok), light.pdf.take(ok)
    contribution = (gather(live.throughput, rows) * gather(albedo, rows) * gather(light.radiance, ok)
                    * (ISOTROPIC_PDF * mis_weight(pdf, ISOTROPIC_PDF) / pdf))
    return ShadowBatch(origin=gather(origin, ok), direction=gather(direction, ok), t_max=t_max.take(ok),
                       contribution=contribution, slot=live.slot.take(rows),
                       time=None if time is None else time.take(ok), media_mask=live.media_mask.take(rows))


def sealed_in(sealed, medium, origin, direction, t_max) -> np.ndarray:
    """``(N,)``: shadow rays certainly blocked by the visible sphere that
    seals their medium (``MediumTable.sealed``; ``medium (N,)`` each ray's
    medium, -1 for none): the origin lies inside the sphere and the ray
    leaves it at ``T_MIN < t < t_max``, each by the table's margin, far above
    the rounding of the exact sphere test the any-hit query would run, so the
    query would find that hit.  Such a ray adds nothing; dropping it before
    the query changes no pixel.  (Mitsuba's ``volpath`` traces them: glass
    blocks shadow rays there too.)"""
    center, inner, margin = sealed
    valid = medium >= 0
    m = np.where(valid, medium, 0)
    inner, margin = inner.take(m), margin.take(m)  # NaN for unsealed media: every comparison false
    oc = center.take(m, axis=1) - origin.astype(np.float64)
    d = direction.astype(np.float64)
    oc2 = dot(oc, oc)
    h = dot(oc, d)  # |d| = 1: the exit is at h + sqrt(r^2 - (|oc|^2 - h^2))
    radius = inner + margin
    with np.errstate(invalid="ignore"):
        exit_t = h + np.sqrt(radius * radius - oc2 + h * h)
    return (valid & (oc2 < inner * inner) & (exit_t > T_MIN + margin)
            & (exit_t < t_max.astype(np.float64) - margin))


def cross_interfaces(cs: CompiledScene, live: PathBatch, surface, direction, absorbed) -> None:
    """Paths transmitted through a visible surface that also bounds a medium
    (a glass ball full of fog) enter or leave that medium; reflected paths
    stay where they were."""
    medium = cs.media.interface_of.take(surface.primitive_idx)
    rows = true_rows((medium >= 0) & ~absorbed)
    if rows.size == 0:
        return
    # the geometric normal faces the incoming ray: a transmitted direction leaves on its far side
    through = rows.take(true_rows(dot(gather(surface.geometric_normal, rows), gather(direction, rows)) < 0.0))
    live.media_mask[through] = cross(live.media_mask.take(through), medium.take(through),
                                     surface.front_face.take(through))
