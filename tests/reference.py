"""A deliberately plain, scalar, recursive ray tracer for cross-checking.

Written straight from the source documents ("Ray Tracing in One Weekend"
style: one ray at a time, recursion, Python floats, its own random
generator), sharing no code with the wavefront engine, so agreement between
the two is evidence that the vectorised engine transports light as described.
Returns per-pixel means and variances of the samples.
"""

import math

import numpy as np


def _sub(a, b): return (a[0] - b[0], a[1] - b[1], a[2] - b[2])
def _add(a, b): return (a[0] + b[0], a[1] + b[1], a[2] + b[2])
def _mul(a, s): return (a[0] * s, a[1] * s, a[2] * s)
def _dot(a, b): return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
def _cross(a, b): return (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])
def _unit(a): return _mul(a, 1.0 / math.sqrt(_dot(a, a)))


def _random_unit_vector(rng):
    while True:  # the book's rejection sampler: independent of the engine's
        p = (rng.uniform(-1, 1), rng.uniform(-1, 1), rng.uniform(-1, 1))
        q = _dot(p, p)
        if 1e-160 < q <= 1:
            return _mul(p, 1 / math.sqrt(q))


def _hit(scene, o, d, t_min=1e-3):
    """Nearest hit: ``(t, point, outward normal, material name)`` or ``(inf, None, None, None)``.

    Untransformed shapes only (transforms are tested on their own).  Quads
    follow RTOW book 2; triangles use a plane hit and three edge tests, a
    different algorithm from the engine's Moller-Trumbore.
    """
    best, found = math.inf, (None, None, None)
    for s in scene.spheres:
        assert s.transform is None
        c, r = s.center, s.radius
        oc = _sub(c, o)
        a = _dot(d, d)
        h = _dot(d, oc)
        disc = h * h - a * (_dot(oc, oc) - r * r)
        if disc < 0:
            continue
        sq = math.sqrt(disc)
        for t in ((h - sq) / a, (h + sq) / a):
            if t_min < t < best:
                p = _add(o, _mul(d, t))
                best, found = t, (p, _mul(_sub(p, c), 1 / r), s.material)
                break
    for q in getattr(scene, "quads", ()):
        assert q.transform is None
        n = _cross(q.u, q.v)
        normal = _unit(n)
        denom = _dot(normal, d)
        if abs(denom) < 1e-12:
            continue
        t = (_dot(normal, q.corner) - _dot(normal, o)) / denom
        if not t_min < t < best:
            continue
        p = _add(o, _mul(d, t))
        planar = _sub(p, q.corner)
        w = _mul(n, 1 / _dot(n, n))
        alpha, beta = _dot(w, _cross(planar, q.v)), _dot(w, _cross(q.u, planar))
        if 0 <= alpha <= 1 and 0 <= beta <= 1:
            best, found = t, (p, normal, q.material)
    for tri in getattr(scene, "triangles", ()):
        assert tri.transform is None
        v0, v1, v2 = tri.vertices
        normal = _unit(_cross(_sub(v1, v0), _sub(v2, v0)))
        denom = _dot(normal, d)
        if abs(denom) < 1e-12:
            continue
        t = _dot(normal, _sub(v0, o)) / denom
        if not t_min < t < best:
            continue
        p = _add(o, _mul(d, t))
        # inside when p is on the inner side of all three edges
        if all(_dot(normal, _cross(_sub(b, a), _sub(p, a))) >= 0 for a, b in ((v0, v1), (v1, v2), (v2, v0))):
            best, found = t, (p, normal, tri.material)
    return (best, *found)


def _color(scene, o, d, depth, rng):
    if depth <= 0:
        return (0.0, 0.0, 0.0)
    t, p, outward, material = _hit(scene, o, d)
    if material is None:
        bg = scene.background
        if bg.type == "solid":
            return tuple(bg.color)
        a = 0.5 * (_unit(d)[1] + 1)
        return tuple((1 - a) * b + a * tp for b, tp in zip(bg.bottom, bg.top))
    front = _dot(d, outward) < 0
    n = outward if front else _mul(outward, -1)
    m = scene.materials[material]
    if m.kind == "emissive":
        return tuple(m.color) if front else (0.0, 0.0, 0.0)  # one-sided, as in RTOW book 3
    if m.kind == "lambertian":
        sd = _add(n, _random_unit_vector(rng))
        if all(abs(x) < 1e-8 for x in sd):
            sd = n
        att = m.albedo
    elif m.kind == "metal":
        ud = _unit(d)
        refl = _sub(ud, _mul(n, 2 * _dot(ud, n)))
        sd = _add(_unit(refl), _mul(_random_unit_vector(rng), m.fuzz))
        if _dot(sd, n) <= 0:
            return (0.0, 0.0, 0.0)
        att = m.albedo
    else:
        ri = 1 / m.refraction_index if front else m.refraction_index
        ud = _unit(d)
        cos_t = min(_dot(_mul(ud, -1), n), 1.0)
        sin_t = math.sqrt(1 - cos_t * cos_t)
        r0 = ((1 - ri) / (1 + ri)) ** 2
        if ri * sin_t > 1 or r0 + (1 - r0) * (1 - cos_t) ** 5 > rng.random():
            sd = _sub(ud, _mul(n, 2 * _dot(ud, n)))
        else:
            perp = _mul(_add(ud, _mul(n, cos_t)), ri)
            par = _mul(n, -math.sqrt(abs(1 - _dot(perp, perp))))
            sd = _add(perp, par)
        att = (1.0, 1.0, 1.0)
    c = _color(scene, p, sd, depth - 1, rng)
    return (att[0] * c[0], att[1] * c[1], att[2] * c[2])


def reference_render(scene, seed=12345):
    """Per-pixel sample mean and variance, each of shape (H, W, 3)."""
    rng = np.random.default_rng(seed)
    cam = scene.camera
    w, h, spp = scene.width, scene.height, scene.render.samples_per_pixel
    look_from = tuple(map(float, cam.look_from))
    fwd = _sub(cam.look_at, look_from)
    focus = cam.focus_dist if cam.focus_dist is not None else math.sqrt(_dot(fwd, fwd))
    wv = _unit(_mul(fwd, -1))
    u = _unit(_cross(cam.vup, wv))
    v = _cross(wv, u)
    vh = 2 * math.tan(math.radians(cam.vfov) / 2) * focus
    vw = vh * w / h
    du, dv = _mul(u, vw / w), _mul(v, -vh / h)
    ul = _sub(_sub(_sub(look_from, _mul(wv, focus)), _mul(u, vw / 2)), _mul(v, -vh / 2))
    lens = focus * math.tan(math.radians(cam.defocus_angle / 2))
    mean = np.zeros((h, w, 3))
    var = np.zeros((h, w, 3))
    for j in range(h):
        for i in range(w):
            samples = []
            for _ in range(spp):
                target = _add(_add(ul, _mul(du, i + rng.random())), _mul(dv, j + rng.random()))
                origin = look_from
                if lens > 0:
                    while True:
                        a, b = rng.uniform(-1, 1), rng.uniform(-1, 1)
                        if a * a + b * b < 1:
                            break
                    origin = _add(origin, _add(_mul(u, a * lens), _mul(v, b * lens)))
                samples.append(_color(scene, origin, _sub(target, origin), scene.render.depth, rng))
            arr = np.array(samples)
            mean[j, i] = arr.mean(axis=0)
            var[j, i] = arr.var(axis=0, ddof=1)
    return mean, var
