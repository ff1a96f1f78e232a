"""Whitted-style ray tracing with Phong shading, through the wavefront engine.

Follows the Whitted/Phong source document (``003_84cf6c3439c95e69.txt``):
at every hit the colour is

    k_a * ambient + sum over unshadowed lights [k_d * light * max(0, n.l)
                                                + k_s * light * max(0, r.v)^shininess]

with ``l`` the unit vector to the light, ``v`` the unit vector to the eye and
``r = 2 (n.l) n - l``, plus, while depth remains, ``k_r`` times the colour
seen along the mirror-reflected ray, added whether or not the point is in
shadow.  ``max_depth`` counts those recursive rays (3 by default).

There is no recursion in code: a wavefront of rays with a per-ray weight (the
product of ``k_r`` along its history) is intersected, shaded, and replaced by
its reflected rays.  Shadow rays are one more batch per light.  Other
material kinds, so that any scene renders sensibly:

* lambertian: Phong with only a diffuse term (``k_d = albedo``);
* metal: a mirror with ``k_r = albedo`` and no local term (fuzz is ignored);
* dielectric: splits into a reflected ray weighted by Schlick's reflectance
  and a refracted ray weighted by the rest (all reflected under total
  internal reflection), both followed;
* emissive: its colour seen from the front (one-sided, as under ``path``),
  black from behind, and the ray ends.
"""

from __future__ import annotations

import numpy as np

from .batch import PathBatch
from .units import Job
from .path import TraceStats, begin_trace, camera_paths, render_sampler
from .scene import CompiledScene
from .vecmath import dot, normalize, reflect, refract, schlick

# A secondary ray whose weight is below this in every channel cannot change
# an 8-bit pixel; dropping it keeps glass splitting from doubling the
# wavefront at every level.
MIN_WEIGHT = 1e-6
# Camera rays per wavefront, as a fraction of the capacity: glass splits let
# a wavefront grow, and a chunk's descendants are never separated, so each
# sample's contributions are always added in the same order.  A chunk whose
# next generation would outgrow the capacity (glass in a mirror box splits
# without end) is traced again as two halves, its radiance restored first,
# so the wavefront never holds more than the capacity the budget sized.
CHUNK_FRACTION = 4
# Rays one sample may have in a generation: beyond it only its heaviest rays
# go on.  A fixed number, not a share of the capacity, so the image does not
# depend on the budget or the worker count; it is at most the smallest
# capacity (render.MIN_CAPACITY), so a chunk of one sample always fits.
MAX_SAMPLE_RAYS = 256


def phong_local(cs: CompiledScene, point, normal, view, material, diffuse=None, time=None) -> np.ndarray:
    """Ambient plus, for each light a shadow ray does not block, diffuse and
    specular; ``diffuse (3, N)`` is the hits' textured diffuse colour, if any."""
    t = cs.materials
    color = t.ambient[:, material] * np.asarray(cs.scene.ambient, dtype=cs.dtype)[:, None]
    specular, shininess = t.specular[:, material], t.shininess[material]
    diffuse = t.albedo[:, material] if diffuse is None else diffuse
    for k in range(cs.light_position.shape[1]):
        to_light = cs.light_position[:, k:k + 1] - point
        distance = np.sqrt(dot(to_light, to_light))
        l = to_light / distance
        lit = ~cs.shapes.occluded(point, l, distance, time)  # any-hit: shadow rays stop at their first hit
        n_dot_l = dot(normal, l)
        r = 2.0 * n_dot_l * normal - l
        highlight = np.maximum(0.0, dot(r, view)) ** shininess
        light = cs.light_color[:, k:k + 1]
        color += lit * light * (diffuse * np.maximum(0.0, n_dot_l) + specular * highlight)
    return color


def heaviest_per_sample(slot, keep_r, keep_t, mirror_weight, refract_weight):
    """``keep_r, keep_t`` (the reflected and refracted rays that go on, as rows
    of the generation) without each sample's rays beyond its
    ``MAX_SAMPLE_RAYS`` heaviest (ties: the earlier row), in their order."""
    next_slot = np.concatenate((slot[keep_r], slot[keep_t]))
    if next_slot.size <= MAX_SAMPLE_RAYS:
        return keep_r, keep_t
    # rays a sample (a chunk's slots are consecutive: a count, not a sort, every generation)
    counts = np.bincount(next_slot - next_slot.min())
    if counts.max() <= MAX_SAMPLE_RAYS:
        return keep_r, keep_t
    counts = counts[counts > 0]  # the samples present, in slot order, as the sort below groups them
    weight = np.concatenate((mirror_weight[:, keep_r].max(axis=0), refract_weight[:, keep_t].max(axis=0)))
    order = np.lexsort((np.arange(next_slot.size), -weight, next_slot))  # by sample, heaviest first
    group_start = np.repeat(np.cumsum(counts) - counts, counts)  # each sorted row's sample's first position
    kept = np.sort(order[np.arange(order.size) - group_start < MAX_SAMPLE_RAYS])
    split = np.searchsorted(kept, keep_r.size)
    return keep_r[kept[:split]], keep_t[kept[split:] - keep_r.size]


def trace_whitted(cs: CompiledScene, job: Job, key, capacity: int, stats: TraceStats | None = None,
                  should_stop=None) -> np.ndarray:
    """Radiance of every sample of ``job``; shape ``(3, job.size)``.

    ``should_stop`` is polled once per bounce; when it returns True the
    trace returns early with incomplete radiance, which the caller discards.
    """
    scene, frame, radiance, stats = begin_trace(cs, job, stats)
    sampler = render_sampler(cs, key)
    max_depth = scene.render.depth
    t = cs.materials
    emissive, dielectric = t.code("emissive"), t.code("dielectric")

    def add(slot, value):
        # a glass split gives one sample two rays in a batch: accumulate with add.at
        np.add.at(radiance, (slice(None), slot), value)

    def trace_chunk(start: int, stop: int) -> bool:
        """Trace samples ``start:stop``; False (their radiance as before) if a
        generation would outgrow ``capacity``."""
        saved, segments = radiance[:, start:stop].copy(), stats.segments
        # one sample per pixel goes through the pixel centre, as in the classic ray tracer
        live = camera_paths(cs, frame, sampler, job, start, stop,
                            pixel_centres=scene.render.samples_per_pixel == 1)
        while len(live):
            if should_stop is not None and should_stop():
                return True
            stats.segments += len(live)
            hits = cs.shapes.intersect(live.origin, live.direction, time=live.time)
            hit = hits.primitive_idx >= 0
            esc = np.flatnonzero(~hit)
            if esc.size:
                add(live.slot[esc], live.throughput[:, esc] * scene.background.radiance(live.direction[:, esc]))
            hit_idx = np.flatnonzero(hit)
            if hit_idx.size == 0:
                break
            time = None if live.time is None else live.time[hit_idx]
            surface = cs.shapes.surface(live.origin[:, hit_idx], live.direction[:, hit_idx], hits.t[hit_idx],
                                        hits.primitive_idx[hit_idx], uv=t.needs_uv, time=time)
            point, normal, front_face, material = surface.point, surface.normal, surface.front_face, surface.material_idx
            kind = t.kind[material]
            d = live.direction[:, hit_idx]
            weight = live.throughput[:, hit_idx]
            slot = live.slot[hit_idx]

            glows = kind == emissive  # emission is one-sided: only the front face glows, but any face ends the ray
            shines = glows & front_face
            uv = surface.uv
            if t.textures is None:
                add(slot[shines], weight[:, shines] * t.emission[:, material[shines]])
            else:
                add(slot[shines], weight[:, shines] * t.emission_at(material[shines], point[:, shines],
                                                                     None if uv is None else uv[:, shines]))
            glass = kind == dielectric
            shaded = ~(glows | glass)
            diffuse = None if t.textures is None else t.albedo_at(material[shaded], point[:, shaded],
                                                                  None if uv is None else uv[:, shaded])
            add(slot[shaded], weight[:, shaded] * phong_local(
                cs, point[:, shaded], normal[:, shaded], -d[:, shaded], material[shaded], diffuse,
                None if time is None else time[shaded]))
            if live.depth[0] >= max_depth:  # a generation shares one depth
                break

            # secondary rays: mirror reflection weighted by k_r ...
            reflectivity = t.reflectivity[:, material]
            if t.textures is not None:  # a textured metal is a mirror tinted by its texture
                tinted = np.flatnonzero((kind == t.code("metal")) & (t.albedo_texture[material] >= 0))
                reflectivity[:, tinted] = t.albedo_at(material[tinted], point[:, tinted],
                                                      None if uv is None else uv[:, tinted])
            mirror_weight = np.where(shaded, weight * reflectivity, 0.0)
            # ... and for glass, reflection and refraction weighted by Schlick
            ratio = np.where(front_face, 1.0 / t.refraction_index[material], t.refraction_index[material])
            cos_theta = np.minimum(-dot(d, normal), 1.0)
            sin_theta = np.sqrt(np.maximum(0.0, 1.0 - cos_theta * cos_theta))
            reflectance = np.where(ratio * sin_theta > 1.0, 1.0, schlick(cos_theta, ratio))
            mirror_weight = np.where(glass, weight * reflectance, mirror_weight)
            refract_weight = weight * (1.0 - reflectance)

            keep_r = np.flatnonzero(mirror_weight.max(axis=0) > MIN_WEIGHT)
            keep_t = np.flatnonzero(glass & (refract_weight.max(axis=0) > MIN_WEIGHT))
            keep_r, keep_t = heaviest_per_sample(slot, keep_r, keep_t, mirror_weight, refract_weight)
            if keep_r.size + keep_t.size > capacity and stop - start > 1:
                radiance[:, start:stop], stats.segments = saved, segments
                return False
            reflected = normalize(reflect(d[:, keep_r], normal[:, keep_r]))
            depth = live.depth[hit_idx] + 1
            refracted = normalize(refract(d[:, keep_t], normal[:, keep_t], ratio[keep_t]))
            live = PathBatch(
                origin=np.concatenate((point[:, keep_r], point[:, keep_t]), axis=1),
                direction=np.concatenate((reflected, refracted), axis=1),
                throughput=np.concatenate((mirror_weight[:, keep_r], refract_weight[:, keep_t]), axis=1),
                slot=np.concatenate((slot[keep_r], slot[keep_t])),
                state=np.concatenate((live.state[hit_idx][keep_r], live.state[hit_idx][keep_t])),
                depth=np.concatenate((depth[keep_r], depth[keep_t])),
                time=None if time is None else np.concatenate((time[keep_r], time[keep_t])),
            )
        return True

    chunk = max(1, capacity // CHUNK_FRACTION)
    todo = [(start, min(job.size, start + chunk)) for start in range(0, job.size, chunk)][::-1]
    while todo:  # a stack, first chunk on top; a chunk that outgrew the capacity comes back as two halves
        start, stop = todo.pop()
        if not trace_chunk(start, stop):
            middle = (start + stop) // 2
            todo += [(middle, stop), (start, middle)]
        elif should_stop is not None and should_stop():
            break
    return radiance
