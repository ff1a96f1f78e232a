"""Build the Mitsuba 3 equivalent of a wavefront scene, for timing side by side.

The translation keeps the work the same: the same shapes (spheres; quads and
boxes' faces as ``rectangle`` shapes; triangles and meshes as ``ply`` files
written in world space), camera (a thin lens
when there is defocus), image size, samples per pixel and maximum path
length, a box pixel filter, and the ``path`` integrator.  The sky gradient
becomes a latitude-longitude environment bitmap.  Materials map to their
nearest Mitsuba plugin: lambertian -> ``diffuse``, metal -> ``conductor``
(fuzz 0) or ``roughconductor`` with ``alpha = fuzz`` (the lobes differ; fine
for timing), dielectric -> ``dielectric``, emissive -> an ``area`` emitter,
which in Mitsuba as in wavefront emits on the front side only (a rectangle's
normal is mapped to ``cross(u, v)``).

Textures become their average colour (``wavefront.textures.mean_color``), a
moving sphere stands still at its mid-shutter centre, and participating media
become Mitsuba ``homogeneous`` media (``sigma_t`` = density, the average
albedo, isotropic phase) behind ``null``-BSDF boundaries with the
``volpath`` integrator; a boundary that coincides with a visible sphere puts
the medium inside that sphere instead, and the camera gets the medium it
stands in.  The work is comparable, not identical: timing, not images.
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


def mitsuba_scene_dict(scene, mi, russian_roulette=True, workdir="."):
    """Mitsuba's dict for a wavefront scene.  ``russian_roulette=False`` sets
    ``rr_depth`` past ``max_depth``: Mitsuba's default ends paths at random from
    depth 5 on, wavefront (like the books) only at ``max_depth``.  Triangles
    and meshes are written to PLY files in ``workdir``."""
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
    from wavefront.textures import mean_color

    rgb = lambda v: {"type": "rgb", "value": [float(x) for x in mean_color(v)]}  # noqa: E731

    def material(name, shape):
        m = scene.materials[name]
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
        return shape

    from wavefront.shapes.sphere import world_center1, world_sphere

    media = medium_dicts(scene, mi, doc, workdir) if scene.media else {}
    for i, sphere in enumerate(scene.spheres):
        center, radius = world_sphere(sphere)
        if sphere.center1 is not None:  # mid-shutter
            center = 0.5 * (center + world_center1(sphere))
        shape = material(sphere.material, {"type": "sphere", "center": center.tolist(), "radius": radius})
        doc[f"sphere{i}"] = shape | media.get((tuple(center.tolist()), radius), {})
    for i, quad in enumerate(scene.quads):
        doc[f"quad{i}"] = material(quad.material, {"type": "rectangle", "to_world": rectangle_to_world(quad, mi)})
    for i, (name, path, smooth) in enumerate(triangle_files(scene, workdir)):
        doc[f"mesh{i}"] = material(name, {"type": "ply", "filename": path, "face_normals": not smooth})
    return doc


def medium_dicts(scene, mi, doc, workdir):
    """Add the scene's media to Mitsuba's ``doc`` (switching it to
    ``volpath``): each a ``homogeneous`` medium, its boundary as ``null``
    shapes with the medium inside and the medium around it outside.  Returns
    ``{(centre, radius): {"interior": ..., "exterior": ...}}`` for boundaries
    that coincide with a visible sphere (that sphere carries the medium)."""
    import os

    import trimesh

    from wavefront.media import boundary_primitives, boundary_volume, contains
    from wavefront.shapes.sphere import world_sphere
    from wavefront.textures import mean_color

    doc["integrator"]["type"] = "volpath"
    volume = [boundary_volume(m) for m in scene.media]
    ref = lambda i: {"type": "ref", "id": f"medium{i}"}  # noqa: E731

    def around(point, inside_of=None):
        """The innermost medium (smallest volume) containing ``point``, other than ``inside_of``."""
        found = [i for i, m in enumerate(scene.media) if i != inside_of and contains(m, point)
                 and (inside_of is None or volume[i] > volume[inside_of])]
        return min(found, key=lambda i: volume[i]) if found else None

    for i, m in enumerate(scene.media):
        doc[f"medium{i}"] = {"type": "homogeneous", "sigma_t": float(m.density),
                             "albedo": {"type": "rgb", "value": [float(x) for x in mean_color(m.albedo)]},
                             "phase": {"type": "isotropic"}}
    camera = around(scene.camera.look_from)
    if camera is not None:
        doc["sensor"]["medium"] = ref(camera)
    visible = {(tuple(c.tolist()), r) for c, r in (world_sphere(s) for s in scene.spheres if s.center1 is None)}
    carried = {}
    for i, m in enumerate(scene.media):
        kind, value = boundary_primitives(m)
        probe = value[0] if kind == "sphere" else (value[0].world()[0] if kind == "quads" else value["v0"][:, 0])
        outside = around(np.asarray(probe, dtype=float) + 1e-3, inside_of=i)
        sides = {"interior": ref(i)} | ({} if outside is None else {"exterior": ref(outside)})
        if kind == "sphere":
            key = (tuple(np.asarray(value[0], dtype=float).tolist()), float(value[1]))
            if key in visible:
                carried[key] = sides
                continue
            doc[f"boundary{i}"] = {"type": "sphere", "center": list(key[0]), "radius": key[1],
                                   "bsdf": {"type": "null"}} | sides
        elif kind == "quads":
            for k, q in enumerate(value):
                doc[f"boundary{i}_{k}"] = {"type": "rectangle", "to_world": rectangle_to_world(q, mi),
                                           "bsdf": {"type": "null"}} | sides
        else:
            v = np.stack((value["v0"], value["v1"], value["v2"]), axis=1).T.reshape(-1, 3)
            path = os.path.join(workdir, f"boundary{i}.ply")
            trimesh.Trimesh(v, np.arange(v.shape[0]).reshape(-1, 3), process=False).export(path)
            doc[f"boundary{i}"] = {"type": "ply", "filename": path, "bsdf": {"type": "null"}} | sides
    return carried


def rectangle_to_world(quad, mi):
    """Mitsuba's rectangle is [-1, 1]^2 in the xy plane facing +z: map it onto
    ``corner + a u + b v`` with +z onto ``cross(u, v)``, the quad's front."""
    corner, u, v = quad.world()
    n = np.cross(u, v)
    m = np.eye(4)
    m[:3, 0], m[:3, 1], m[:3, 2] = u / 2, v / 2, n / np.linalg.norm(n)
    m[:3, 3] = corner + u / 2 + v / 2
    return mi.ScalarTransform4f(m.tolist())


def triangle_files(scene, workdir):
    """World-space PLY files (written by trimesh) for the loose triangles, one
    per material, and for each mesh: ``[(material, path, smooth)]``."""
    import os

    import trimesh

    from wavefront.shapes import mesh_triangles

    out = []
    by_material = {}
    for t in scene.triangles:
        by_material.setdefault(t.material, []).append(t.world())
    for k, (name, tris) in enumerate(by_material.items()):
        v = np.concatenate(tris)
        path = os.path.join(workdir, f"triangles{k}.ply")
        trimesh.Trimesh(v, np.arange(v.shape[0]).reshape(-1, 3), process=False).export(path)
        out.append((name, path, False))
    for k, mesh in enumerate(scene.meshes):
        vertices = mesh.vertices if mesh.transform is None else mesh.transform.points(mesh.vertices.T).T
        path = os.path.join(workdir, f"mesh{k}.ply")
        normals = None
        if mesh.smooth and mesh.vertex_normals is not None:
            tri = mesh_triangles(mesh)  # world-space normals, as wavefront shades them
            normals = np.zeros_like(vertices)
            normals[mesh.faces[:, 0]] = tri["vertex_normal"][0].T
            normals[mesh.faces[:, 1]] = tri["vertex_normal"][1].T
            normals[mesh.faces[:, 2]] = tri["vertex_normal"][2].T
        trimesh.Trimesh(vertices, mesh.faces, vertex_normals=normals, process=False).export(path)
        out.append((mesh.material, path, mesh.smooth))
    return out


def save_scene_dict(doc, mi, path):
    """Write Mitsuba's dict as JSON, for a process that loads it without
    wavefront: transforms as 4x4 matrices, bitmaps as ``.npy`` files next to
    ``path`` (Mitsuba 3 has no writer of its XML format)."""
    import json
    import os

    def plain(value, key):
        if isinstance(value, dict):
            return {k: plain(v, f"{key}_{k}") for k, v in value.items()}
        if isinstance(value, mi.ScalarTransform4f):
            return {"__transform__": np.array(value.matrix, dtype=np.float64).tolist()}
        if isinstance(value, mi.Bitmap):
            file = os.path.splitext(path)[0] + f"{key}.npy"
            np.save(file, np.array(value))
            return {"__bitmap__": file}
        return value

    with open(path, "w") as f:
        json.dump(plain(doc, ""), f)


def load_scene_dict(path, mi):
    """The dict :func:`save_scene_dict` wrote, with Mitsuba's objects rebuilt."""
    import json

    def rebuild(value):
        if isinstance(value, dict):
            if "__transform__" in value:
                return mi.ScalarTransform4f(value["__transform__"])
            if "__bitmap__" in value:
                return mi.Bitmap(np.load(value["__bitmap__"]))
            return {k: rebuild(v) for k, v in value.items()}
        return value

    with open(path) as f:
        return rebuild(json.load(f))
