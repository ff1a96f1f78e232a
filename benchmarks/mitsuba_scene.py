"""Build the Mitsuba 3 equivalent of a wavefront scene, for timing side by side.

The translation keeps the work the same: the same spheres, camera (a thin lens
when there is defocus), image size, samples per pixel and maximum path
length, a box pixel filter, and the ``path`` integrator.  The sky gradient
becomes a latitude-longitude environment bitmap.  Materials map to their
nearest Mitsuba plugin: lambertian -> ``diffuse``, metal -> ``conductor``
(fuzz 0) or ``roughconductor`` with ``alpha = fuzz`` (the lobes differ; fine
for timing), dielectric -> ``dielectric``, emissive -> an ``area`` emitter.
"""

from __future__ import annotations

import math

import numpy as np


def sky_bitmap(background, height=64):
    """Lat-long image of a wavefront background: rows run from +y down to -y."""
    theta = (np.arange(height) + 0.5) / height * math.pi
    y = np.cos(theta)
    a = 0.5 * (y + 1.0)
    bottom = np.asarray(background.bottom, dtype=np.float32)
    top = np.asarray(background.top, dtype=np.float32)
    rows = (1 - a)[:, None] * bottom + a[:, None] * top
    return np.repeat(rows[:, None, :], 2 * height, axis=1).astype(np.float32)


def mitsuba_scene_dict(scene, mi, russian_roulette=True):
    """Mitsuba's dict for a wavefront scene.  ``russian_roulette=False`` sets
    ``rr_depth`` past ``max_depth``: Mitsuba's default ends paths at random from
    depth 5 on, wavefront (like the books) only at ``max_depth``."""
    cam = scene.camera
    look_from = np.asarray(cam.look_from, dtype=float)
    look_at = np.asarray(cam.look_at, dtype=float)
    focus = cam.focus_dist if cam.focus_dist is not None else float(np.linalg.norm(look_at - look_from))
    sensor = {
        "type": "thinlens" if cam.defocus_angle > 0 else "perspective",
        "fov": cam.vfov,
        "fov_axis": "y",
        "to_world": mi.ScalarTransform4f().look_at(origin=look_from.tolist(), target=look_at.tolist(),
                                                   up=list(cam.vup)),
        "film": {"type": "hdrfilm", "width": scene.width, "height": scene.height,
                 "rfilter": {"type": "box"}, "pixel_format": "rgb"},
        "sampler": {"type": "independent", "sample_count": scene.render.samples_per_pixel},
    }
    if cam.defocus_angle > 0:
        sensor["aperture_radius"] = focus * math.tan(math.radians(cam.defocus_angle / 2))
        sensor["focus_distance"] = focus
    doc = {"type": "scene",
           "integrator": {"type": "path", "max_depth": scene.render.depth,
                          **({} if russian_roulette else {"rr_depth": scene.render.depth + 1})},
           "sensor": sensor}
    bg = scene.background
    if bg.type == "sky":
        doc["sky"] = {"type": "envmap", "bitmap": mi.Bitmap(sky_bitmap(bg))}
    else:
        doc["sky"] = {"type": "constant", "radiance": {"type": "rgb", "value": list(bg.color)}}
    for i, sphere in enumerate(scene.spheres):
        m = scene.materials[sphere.material]
        shape = {"type": "sphere", "center": list(sphere.center), "radius": sphere.radius}
        rgb = lambda v: {"type": "rgb", "value": list(v)}  # noqa: E731
        if m.kind in ("lambertian", "phong"):
            shape["bsdf"] = {"type": "diffuse", "reflectance": rgb(m.albedo if m.kind == "lambertian" else m.diffuse)}
        elif m.kind == "metal":
            if m.fuzz > 0:
                shape["bsdf"] = {"type": "roughconductor", "alpha": m.fuzz, "specular_reflectance": rgb(m.albedo)}
            else:
                shape["bsdf"] = {"type": "conductor", "specular_reflectance": rgb(m.albedo)}
        elif m.kind == "dielectric":
            shape["bsdf"] = {"type": "dielectric", "int_ior": float(m.refraction_index), "ext_ior": 1.0}
        else:
            shape["bsdf"] = {"type": "diffuse", "reflectance": rgb((0, 0, 0))}
            shape["emitter"] = {"type": "area", "radiance": rgb(m.color)}
        doc[f"sphere{i}"] = shape
    return doc
