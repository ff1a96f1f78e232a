"""The wavefront path integrator (backward path tracing, RTIOW books 1-2).

One call to :func:`trace_paths` runs a job's samples through a fixed-capacity
wavefront.  Each iteration is a list of named stages over *all* live paths:

1. **refill** free slots with camera rays of new samples (so a long tail of a
   few deep paths never costs a near-empty NumPy call per bounce);
2. **intersect** every path with every shape (brute force or the BVH), and
   describe each hit in one :class:`~wavefront.shapes.SurfaceHits`;
3. **escaped** paths add ``throughput * background`` and end;
4. **emitted**: paths that hit an emitter end; those that struck its front
   side add ``throughput * color``;
5. **scatter**: hits are routed by material kind, one kernel per kind
   present, and throughput is multiplied by the attenuation; absorbed paths
   end, and so do paths that have reached ``max_depth`` segments;
6. **compact** the survivors.

A path ends in one of the book's three ways: it hits a light, escapes to the
background, or reaches the depth limit (contributing nothing more).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .batch import PathBatch
from .units import Job
from .materials import scatter_dielectric, scatter_lambertian, scatter_metal
from .sampling import bounce_dimension, path_state, uniform_pairs, uniform_pairs_at
from .scene import CompiledScene
from .vecmath import gather, scatter, scatter_add

REFILL_FRACTION = 0.5  # refill once fewer than half the slots are live


@dataclass
class TraceStats:
    segments: int = 0  # rays traced (camera rays + scattered rays)
    samples: int = 0


def camera_paths(cs: CompiledScene, frame, key, job: Job, start: int, stop: int,
                 pixel_centres: bool = False) -> PathBatch:
    """Stage 1: new paths for the job's slots ``start:stop``.

    ``pixel_centres`` puts every sample at its pixel's centre instead of
    jittering it (classic Whitted with one sample per pixel).
    """
    pixel, sample_id = job.samples(start, stop)
    state = path_state(key, sample_id)
    u = np.concatenate((uniform_pairs(state, 0), uniform_pairs(state, 1)))
    if pixel_centres:
        u[:2] = 0.5
    origin, direction = frame.generate_rays(pixel, u)  # in float64, then at the render's precision
    origin, direction = origin.astype(cs.dtype, copy=False), direction.astype(cs.dtype, copy=False)
    n = stop - start
    return PathBatch(
        origin=origin,
        direction=direction,
        throughput=np.ones((3, n), dtype=origin.dtype),
        slot=np.arange(start, stop, dtype=np.int64),
        state=state,
        depth=np.zeros(n, dtype=np.int32),
    )


def _lambertian(table, m, d, n, front_face, u):
    return scatter_lambertian(d, n, front_face, gather(table.albedo, m), u)


def _metal(table, m, d, n, front_face, u):
    return scatter_metal(d, n, front_face, gather(table.albedo, m), table.fuzz.take(m), u)


def _dielectric(table, m, d, n, front_face, u):
    return scatter_dielectric(d, n, front_face, table.refraction_index.take(m), u)


# Which material kinds each scatter kernel serves.  Phong surfaces are
# lambertian with albedo = diffuse under the path integrator.
_KERNELS = ((("lambertian", "phong"), _lambertian), (("metal",), _metal), (("dielectric",), _dielectric))


def kernels_present(table):
    """(kind codes, kernel) for the kinds present in the scene only."""
    present = set(np.unique(table.kind).tolist())
    out = []
    for kinds, kernel in _KERNELS:
        codes = tuple(c for c in (table.code(k) for k in kinds) if c in present)
        if codes:
            out.append((np.array(codes, dtype=np.int8), kernel))
    return out


def begin_trace(cs: CompiledScene, job: Job, stats: TraceStats | None):
    """What every integrator starts from: the camera frame, a zeroed
    per-sample radiance buffer and the counters (the job's samples counted)."""
    scene = cs.scene
    stats = stats if stats is not None else TraceStats()
    stats.samples += job.size
    return scene, scene.camera.frame(scene.width, scene.height), np.zeros((3, job.size)), stats


def trace_paths(cs: CompiledScene, job: Job, key, capacity: int, stats: TraceStats | None = None,
                should_stop=None) -> np.ndarray:
    """Radiance of every sample of ``job``; shape ``(3, job.size)``.

    The loop is the list of stages; each is a function over the live
    :class:`PathBatch`.  ``should_stop`` is polled once per bounce; when it
    returns True the trace returns early with incomplete radiance, which the
    caller discards.
    """
    scene, frame, radiance, stats = begin_trace(cs, job, stats)
    kernels = kernels_present(cs.materials)
    live, next_slot = camera_paths(cs, frame, key, job, 0, 0), 0
    while True:
        live, next_slot = refill(cs, frame, key, job, live, next_slot, capacity)
        if len(live) == 0 or (should_stop is not None and should_stop()):
            break
        stats.segments += len(live)
        hits = cs.shapes.intersect(live.origin, live.direction)
        live, surface = escaped(cs, live, hits, radiance)
        if len(live) == 0:
            continue
        absorbed = emitted(cs, live, surface, radiance)
        direction, absorbed = scatter_hits(cs, kernels, live, surface, absorbed)
        live = advance(live, surface, direction, absorbed, scene.render.depth)
    return radiance


def refill(cs: CompiledScene, frame, key, job: Job, live: PathBatch, next_slot: int, capacity: int):
    """Stage 1: free slots take camera rays of the job's next samples, once
    enough are free (so a long tail of a few deep paths never costs a
    near-empty NumPy call per bounce).  Returns the batch and the next slot."""
    free = capacity - len(live)
    if next_slot < job.size and (len(live) == 0 or free >= capacity * REFILL_FRACTION):
        stop = min(job.size, next_slot + free)
        live = PathBatch.concat(live, camera_paths(cs, frame, key, job, next_slot, stop))
        next_slot = stop
    return live, next_slot


def escaped(cs: CompiledScene, live: PathBatch, hits, radiance):
    """Stage 3: paths that hit nothing add ``throughput * background`` and
    end.  Returns the paths that hit something and what they hit."""
    hit = hits.primitive_idx >= 0
    esc_idx = np.flatnonzero(~hit)
    if esc_idx.size:
        scatter_add(radiance, live.slot.take(esc_idx),
                    gather(live.throughput, esc_idx) * cs.scene.background.radiance(gather(live.direction, esc_idx)))
    # from here on only the hit rows matter: compact once
    hit_idx = np.flatnonzero(hit) if esc_idx.size else np.arange(len(live))
    live = live.take(hit_idx) if esc_idx.size else live
    if len(live) == 0:
        return live, None
    surface = cs.shapes.surface(live.origin, live.direction, hits.t.take(hit_idx), hits.primitive_idx.take(hit_idx))
    return live, surface


def emitted(cs: CompiledScene, live: PathBatch, surface, radiance) -> np.ndarray:
    """Stage 4: paths that hit an emitter end there, adding ``throughput *
    color`` if they struck its front side (emission is one-sided, as in RTOW
    book 3, pbrt and Mitsuba: a sphere emits outwards, a quad or triangle on
    its ``cross(u, v)`` / ``cross(v1 - v0, v2 - v0)`` side).  Returns the
    ``absorbed`` mask the later stages extend."""
    table = cs.materials
    absorbed = np.zeros(len(live), dtype=bool)
    emissive = table.code("emissive")
    if not (table.kind == emissive).any():
        return absorbed
    sel = np.flatnonzero(table.kind.take(surface.material_idx) == emissive)
    if sel.size:
        absorbed[sel] = True
        sel = sel[surface.front_face.take(sel)]
        m = surface.material_idx.take(sel)
        scatter_add(radiance, live.slot.take(sel), gather(live.throughput, sel) * gather(table.emission, m))
    return absorbed


def scatter_hits(cs: CompiledScene, kernels, live: PathBatch, surface, absorbed):
    """Stage 5: hits are routed by material kind, one kernel per kind present;
    throughput is multiplied by the attenuation.  Returns the new directions
    and the ``absorbed`` mask."""
    table = cs.materials
    material, normal, front_face = surface.material_idx, surface.normal, surface.front_face
    kind = table.kind.take(material)
    u = uniform_pairs_at(live.state, bounce_dimension(live.depth), cs.dtype)
    if len(kernels) == 1 and not (table.kind == table.code("emissive")).any():
        # a lone kind and no emitters: no routing, no gathers
        att, direction, dead = kernels[0][1](table, material, live.direction, normal, front_face, u)
        live.throughput *= att
        return direction, dead
    direction = live.direction  # overwritten row by row below
    for kind_codes, kernel in kernels:
        sel = np.flatnonzero(np.isin(kind, kind_codes) if len(kind_codes) > 1 else kind == kind_codes[0])
        if sel.size == 0:
            continue
        att, d, dead = kernel(table, material.take(sel), gather(live.direction, sel), gather(normal, sel),
                              front_face.take(sel), gather(u, sel))
        scatter(live.throughput, sel, gather(live.throughput, sel) * att)
        scatter(direction, sel, d)
        absorbed[sel] = dead
    return direction, absorbed


def advance(live: PathBatch, surface, direction, absorbed, max_depth: int) -> PathBatch:
    """Stage 6: paths continue from their hit points; absorbed paths end, and
    so do paths that have used ``max_depth`` segments (they contribute
    nothing more); the survivors are compacted."""
    live.origin = surface.point
    live.direction = direction
    live.depth += 1
    alive = ~absorbed & (live.depth < max_depth)
    if not alive.all():
        live = live.take(np.flatnonzero(alive))
    return live
