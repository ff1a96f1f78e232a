"""Hostile probes of the command and the loaders (session 5): each test is a
defect a probe found, fixed with it."""

import json
import os
import zipfile

import numpy as np
import pytest

from wavefront import Camera, Lambertian, RenderSettings, Scene, Sphere
from wavefront.film import CheckpointError, Film, load_checkpoint, save_checkpoint

from .test_cli import run
from .test_probe_14 import glb_instancing, write_scene

trimesh = pytest.importorskip("trimesh")

ONE_TRIANGLE = b"".join(np.array(v, dtype=np.float32).tobytes() for v in ((0, 0, -2), (1, 0, -2), (0, 1, -2)))
UVS = np.array([(0, 0), (1, 0), (0, 1)], dtype=np.float32).tobytes()


def textured_gltf(folder, buffer="model.bin", image="albedo.png"):
    """A .gltf of one triangle with UVs, its buffer in ``buffer`` and a
    material whose base colour texture is the file ``image`` (which is not
    written: nothing may read it)."""
    (folder / buffer).write_bytes(ONE_TRIANGLE + UVS)
    doc = {"asset": {"version": "2.0"}, "scene": 0, "scenes": [{"nodes": [0]}], "nodes": [{"mesh": 0}],
           "meshes": [{"primitives": [{"attributes": {"POSITION": 0, "TEXCOORD_0": 1}, "material": 0}]}],
           "materials": [{"pbrMetallicRoughness": {"baseColorTexture": {"index": 0}}}],
           "textures": [{"source": 0, "sampler": 0}], "samplers": [{}], "images": [{"uri": image}],
           "buffers": [{"uri": buffer, "byteLength": 60}],
           "bufferViews": [{"buffer": 0, "byteOffset": 0, "byteLength": 36},
                           {"buffer": 0, "byteOffset": 36, "byteLength": 24}],
           "accessors": [{"bufferView": 0, "componentType": 5126, "count": 3, "type": "VEC3",
                          "min": [0, 0, -2], "max": [1, 1, -2]},
                         {"bufferView": 1, "componentType": 5126, "count": 3, "type": "VEC2"}]}
    (folder / "model.gltf").write_text(json.dumps(doc))
    return folder / "model.gltf"


def test_no_output_replaces_a_file_a_gltf_names(tmp_path):
    """``-o albedo.png`` beside a glTF whose material names albedo.png
    replaced it: only the .gltf itself counted as a file the scene reads, not
    the buffers and images it names."""
    textured_gltf(tmp_path, buffer="data.npy")
    (tmp_path / "albedo.png").write_bytes(b"the user's texture")
    scene = write_scene(tmp_path, "image: {width: 4, height: 4}\nmaterials: {m: {type: lambertian}}\n"
                                  "meshes: [{file: model.gltf, material: m}]\n")
    for name, where in (("albedo.png", "images[0]"), ("data.npy", "buffers[0]")):
        before = (tmp_path / name).read_bytes()
        r = run("render", scene, "-o", tmp_path / name, "--spp", 1)
        assert r.returncode == 2 and f"model.gltf names it in {where}" in r.stderr, r.stderr
        assert len(r.stderr.splitlines()) == 1 and (tmp_path / name).read_bytes() == before


def test_a_gltf_image_is_never_decoded_and_its_uvs_are_kept(tmp_path, monkeypatch):
    """trimesh decoded every image a glTF names or holds, though wavefront
    takes materials from the scene: a 420 KB PNG of 12000x12000 pixels took a
    render under --memory 256M to 1.2 GB.  The images are dropped before
    trimesh reads the file; the UVs (read in trimesh's material branch) stay."""
    import PIL.Image

    from wavefront.shapes.mesh import read_mesh

    opened = []
    path = textured_gltf(tmp_path)
    PIL.Image.new("RGB", (4, 4)).save(tmp_path / "albedo.png")
    monkeypatch.setattr(PIL.Image, "open", lambda *args, **kwargs: opened.append(args))  # trimesh catches what follows
    data = read_mesh(str(path))
    assert opened == []
    assert data["faces"].shape == (1, 3)
    np.testing.assert_allclose(np.sort(data["uv"], axis=0), [(0, 0), (0, 1), (1, 1)])  # v flipped: 1 - v


def test_a_glb_with_an_embedded_texture_keeps_its_triangles_and_uvs(tmp_path):
    """The GLB is rewritten without its images (JSON chunk re-padded, lengths
    updated): what trimesh builds from it is what it built before, less the texture."""
    from PIL import Image

    from wavefront.shapes.mesh import read_mesh

    ball = trimesh.creation.icosphere(subdivisions=1)
    uv = np.random.default_rng(1).random((len(ball.vertices), 2))
    ball.visual = trimesh.visual.TextureVisuals(uv=uv, image=Image.new("RGB", (8, 8), (200, 10, 10)))
    path = tmp_path / "ball.glb"
    path.write_bytes(trimesh.Scene(ball).export(file_type="glb"))
    direct = trimesh.load(path, force="mesh", process=False)
    data = read_mesh(str(path))
    assert data["faces"].shape == (80, 3)
    np.testing.assert_allclose(data["vertices"][data["faces"]], np.asarray(direct.vertices)[direct.faces], atol=1e-6)
    np.testing.assert_allclose(data["uv"], np.asarray(direct.visual.uv), atol=1e-6)


def test_a_medium_boundary_mesh_is_checked_against_the_budget_before_loading(tmp_path):
    """A mesh boundary skipped the glTF-instance count of the budget check
    and had a face limit of its own: a 127 KB GLB as a fog boundary reached
    1.2 GB under --memory 256M."""
    from wavefront import MemoryBudgetError, load_scene
    from wavefront.memory import current_rss

    glb_instancing(tmp_path / "many.glb", 3_200)
    scene = write_scene(tmp_path, "materials: {w: {type: lambertian}}\n"
                                  "spheres: [{center: [0, 0, -1], radius: 0.5, material: w}]\n"
                                  "media: [{boundary: {mesh: {file: many.glb}}, density: 1}]\n")
    with pytest.raises(MemoryBudgetError, match=r"media\[0\]\.boundary\.mesh\.file: loading .*many\.glb"):
        load_scene(scene, memory=current_rss() + 300 * 2**20)


def test_a_local_cluster_is_bounded_by_the_budget_and_bad_addresses_are_one_line(tmp_path):
    """``local:99999999999999999999`` grew to 14 GB building Dask's table of
    workers; ``tls://`` without a context and ``ucx://`` raised tracebacks."""
    pytest.importorskip("dask.distributed")
    from wavefront.distributed import SchedulerError, connect

    with pytest.raises(SchedulerError, match=r"at most local:\d+$"):
        connect("local:99999999999999999999", memory=1 << 30)
    with pytest.raises(SchedulerError, match="cannot connect"):
        connect("tls://127.0.0.1:9")


def checkpoint(tmp_path):
    scene = Scene(materials={"m": Lambertian((0.5, 0.5, 0.5))}, spheres=[Sphere((0, 0, -1), 0.5, "m")],
                  camera=Camera(), width=4, height=4, render=RenderSettings(samples_per_pixel=2))
    film = Film(4, 4)
    film.sum[:] = 1.0
    film.count[:] = 1  # what its one unit done (pass 0: 1 spp) gives each pixel
    path = str(tmp_path / "ck.npz")
    save_checkpoint(path, scene, film, 1)
    return scene, path


def test_a_damaged_checkpoint_is_refused_in_one_line(tmp_path):
    """A corrupt deflate stream (zlib.error), an unknown compression method
    (NotImplementedError) and an encrypted member (RuntimeError) escaped as
    tracebacks; pixel sums of NaN were resumed into an image of NaN."""
    scene, path = checkpoint(tmp_path)
    assert load_checkpoint(path, scene, 8)[1] == 1
    with zipfile.ZipFile(path) as z:
        members = {name: z.read(name) for name in z.namelist()}

    def rewrite(name, **arrays):
        out = str(tmp_path / name)
        with zipfile.ZipFile(out, "w", compression=zipfile.ZIP_DEFLATED) as z:
            for member, data in members.items():
                z.writestr(member, data)
        if arrays:
            np.savez(out, **{**{k[:-4]: np.load(path)[k[:-4]] for k in members}, **arrays})
        return out

    nan = np.full((3, 16), np.nan)
    with pytest.raises(CheckpointError, match="not all finite"):
        load_checkpoint(rewrite("nan.npz", sum=nan), scene, 8)
    with pytest.raises(CheckpointError, match="more samples"):
        load_checkpoint(rewrite("count.npz", count=np.full(16, 3, dtype=np.uint32)), scene, 8)
    deflated = rewrite("deflated.npz")
    data = bytearray(open(deflated, "rb").read())
    start = data.index(b"sum.npy") + len("sum.npy") + 40  # inside the sum member's compressed bytes
    data[start:start + 16] = bytes(16)
    with open(deflated, "wb") as f:
        f.write(data)
    with pytest.raises(CheckpointError, match="not a wavefront checkpoint"):
        load_checkpoint(deflated, scene, 8)
    method = bytearray(open(rewrite("method.npz"), "rb").read())
    for at in range(len(method) - 4):  # every local and central header: compression method 99
        if method[at:at + 4] in (b"PK\x03\x04", b"PK\x01\x02"):
            offset = 8 if method[at + 2] == 3 else 10
            method[at + offset:at + offset + 2] = (99).to_bytes(2, "little")
    with open(tmp_path / "method.npz", "wb") as f:
        f.write(method)
    with pytest.raises(CheckpointError, match="not a wavefront checkpoint"):
        load_checkpoint(str(tmp_path / "method.npz"), scene, 8)


def test_control_characters_in_names_are_escaped_in_the_one_line(tmp_path):
    """A newline in a YAML key or a file name split the message in two (the
    second line could pose as another error) and an ESC sequence reached the terminal."""
    scene = write_scene(tmp_path, "spheres: [{center: [0, 0, -1], radius: 0.5, material: 0}]\n"
                                  "materials: {m: {type: lambertian}}\n"
                                  '"x\\nwavefront: error: forged\\e[31m": 1\n')
    r = run("render", scene, "-o", tmp_path / "out.npy", "--spp", 1)
    assert r.returncode == 2 and len(r.stderr.splitlines()) == 1, r.stderr
    assert "\x1b" not in r.stderr and "x\\nwavefront: error: forged\\x1b[31m" in r.stderr
    assert not os.path.exists(tmp_path / "out.npy")


def test_the_api_names_bad_arguments(tmp_path):
    """``load_scene(p, memory='1G')`` raised a TypeError from deep inside, a
    bytes path another, and ``render('x.yaml')`` an AttributeError."""
    from wavefront import load_scene, render

    scene = write_scene(tmp_path, "image: {width: 4, height: 4}\nmaterials: {m: {type: lambertian}}\n"
                                  "spheres: [{center: [0, 0, -1], radius: 0.5, material: m}]\n")
    with pytest.raises(ValueError, match="memory: expected a number of bytes"):
        load_scene(scene, memory="1G")
    with pytest.raises(ValueError, match="memory: at least"):
        load_scene(scene, memory=-1)
    assert load_scene(os.fsencode(scene)).width == 4
    with pytest.raises(TypeError, match="expected a Scene"):
        render(str(scene))


def test_an_obj_of_huge_polygons_is_refused_before_trimesh_builds_them(tmp_path):
    """A 4 MB OBJ whose one face lists 2 M vertices is ~2 M triangles: the
    file-size estimate let it take a render under --memory 200M to 758 MiB
    before the compile step refused it.  Its polygons are counted first."""
    from wavefront import MemoryBudgetError, load_scene
    from wavefront.memory import current_rss
    from wavefront.shapes.mesh import MeshError, _obj_triangle_bound, read_mesh

    fan = tmp_path / "fan.obj"
    fan.write_text("v 0 0 -1\nv 1 0 -1\nv 0 1 -1\nv 1 1 -1\nf " + " ".join(["1 2 3 4"] * 500_000) + "\n")
    with pytest.raises(MeshError, match="more than 1000000 faces"):
        read_mesh(str(fan), max_faces=1_000_000)
    scene = write_scene(tmp_path, "materials: {m: {type: lambertian}}\nmeshes: [{file: fan.obj, material: m}]\n")
    with pytest.raises(MemoryBudgetError, match=r"meshes\[0\]\.file: loading .*fan\.obj"):
        load_scene(scene, memory=current_rss() + 300 * 2**20)
    # a file of triangles: the bound is about their number (trimesh's own export, with normals and uvs)
    ball = trimesh.creation.icosphere(subdivisions=3)
    ball.visual = trimesh.visual.TextureVisuals(uv=np.random.default_rng(0).random((len(ball.vertices), 2)))
    text = trimesh.exchange.obj.export_obj(ball, include_normals=True, include_texture=True).encode()
    assert len(ball.faces) <= _obj_triangle_bound(text) <= len(ball.faces) + 8


@pytest.mark.skipif(not os.path.exists("/dev/stdin"), reason="needs /dev/stdin")
def test_a_scene_read_from_a_pipe_is_held_to_the_budget_before_it_is_parsed(tmp_path):
    """A pipe has no size to check before reading (an 11 MB scene on stdin
    took the command past --memory 64M); its bytes are counted once read."""
    import subprocess
    import sys

    lines = ["image: {width: 4, height: 4}", "materials: {m: {type: lambertian}}", "spheres:"]
    lines += [f"  - {{center: [{i}, 0, -5], radius: 0.5, material: m}}" for i in range(200_000)]
    r = subprocess.run([sys.executable, "-m", "wavefront", "render", "/dev/stdin", "-o", str(tmp_path / "o.npy"),
                        "--memory", "64M"], input="\n".join(lines) + "\n", capture_output=True, text=True, timeout=120)
    # refused once what has been read could not be loaded (read in chunks), not after all 11 MiB
    assert r.returncode == 2 and "loading /dev/stdin (" in r.stderr and "MiB read so far) needs about" in r.stderr, \
        r.stderr
    assert not (tmp_path / "o.npy").exists()


@pytest.mark.skipif(not os.path.exists("/dev/stdin"), reason="needs /dev/stdin")
def test_a_piped_scene_loads_under_the_budget_its_file_loads_under(tmp_path):
    """A piped scene's bytes were counted twice (once held, once in what
    loading them needs): a 19 MiB scene loaded from a file under --memory
    200M but was refused through /dev/stdin.  30 MiB of scene under 300M: a
    file takes the interpreter (~40 MiB) and 8 bytes a byte (240 MiB);
    counted twice it was ~310 MiB."""
    import subprocess
    import sys

    text = "image: {width: 4, height: 4}\nrender: {samples_per_pixel: 1, max_depth: 1}\n"
    text += "materials: {m: {type: lambertian}}\nspheres:\n"
    line = "  - {center: [0, 0, -5], radius: 0.5, material: m}\n  # " + "pad " * 250 + "\n"
    text += line * (30 * 2**20 // len(line))
    scene = tmp_path / "big.yaml"
    scene.write_text(text)
    r = run("render", scene, "-o", tmp_path / "f.npy", "--memory", "300M", "-q")
    assert r.returncode == 0, r.stderr  # the file loads (the test's premise)
    # through a pipe (stdin redirected from the file would be the file itself, with its size)
    r = subprocess.run([sys.executable, "-m", "wavefront", "render", "/dev/stdin", "-o", str(tmp_path / "p.npy"),
                        "--memory", "300M", "-q"], input=text.encode(), capture_output=True, timeout=300)
    assert r.returncode == 0, r.stderr.decode()
    assert np.array_equal(np.load(tmp_path / "f.npy"), np.load(tmp_path / "p.npy"))


def test_an_image_named_by_several_materials_is_decoded_once(tmp_path):
    """One picture on 12 materials was decoded 12 times (~160 MiB for 1024x1024),
    so a budget that held it once refused the scene."""
    from PIL import Image

    from wavefront import load_scene, render

    Image.new("RGB", (16, 8), (200, 100, 50)).save(tmp_path / "wood.png")
    materials = ", ".join(f"m{i}: {{type: lambertian, albedo: {{type: image, file: wood.png}}}}" for i in range(3))
    spheres = ", ".join(f"{{center: [{i - 1}, 0, -3], radius: 0.4, material: m{i}}}" for i in range(3))
    scene = load_scene(write_scene(tmp_path, f"image: {{width: 8, height: 8}}\nmaterials: {{{materials}}}\n"
                                             f"spheres: [{spheres}]\n"))
    pixels = [scene.materials[f"m{i}"].albedo.pixels for i in range(3)]
    assert pixels[0] is pixels[1] is pixels[2] and not pixels[0].flags.writeable
    assert render(scene, workers=1).shape == (8, 8, 3)
    again = load_scene(tmp_path / "scene.yaml")  # another load decodes its own (nothing outlives a load)
    assert again.materials["m0"].albedo.pixels is not pixels[0]


def test_a_document_of_many_small_values_is_held_to_the_budget_while_it_is_built(tmp_path):
    """``name: [[], [], ...]``: 12 MB of file took 339 MiB under --memory 160M
    (the file-size estimate assumes a scene's ~8 bytes of memory a byte).  With a
    budget the values are counted against it as they are built."""
    from wavefront import MemoryBudgetError, load_scene
    from wavefront.memory import current_rss

    path = tmp_path / "lists.yaml"
    path.write_text("name: [" + ",".join(["[]"] * 2_000_000) + "]\n")
    with pytest.raises(MemoryBudgetError, match="holds more than .* values"):
        load_scene(path, memory=current_rss() + 64 * 2**20)


def test_frame_names_are_checked_as_they_are_made(tmp_path):
    """``-o 'f_{frame:>5000}.png' --frames 100000`` built 500 MB of names
    before the first write refused them, in a message of 5,000 characters."""
    from wavefront.cli import frame_paths

    with pytest.raises(ValueError, match="longer than the system allows") as e:
        frame_paths(str(tmp_path / "f_{frame:>5000}.png"), 100_000)
    assert len(str(e.value)) < 400
    assert frame_paths("spin_{frame:03d}.png", 3) == ["spin_000.png", "spin_001.png", "spin_002.png"]


@pytest.mark.parametrize("material, problem", [
    ("{type: dielectric, refraction_index: 1e-300}", "refraction_index: must be >= 1e-06"),
    ("{type: emissive, color: [1e300, 1, 1]}", "color[0]: must be <= 1e+30"),
    ("{type: phong, shininess: 1e300}", "shininess: must be <= 1000000.0"),
])
def test_values_that_overflow_a_render_are_refused_at_load(tmp_path, material, problem):
    """An index of 1e-300, an emitter of 1e300 or an exponent of 1e300 printed
    NumPy overflow warnings (the emitter then rendered black, its samples
    dropped as non-finite)."""
    scene = write_scene(tmp_path, f"image: {{width: 4, height: 4}}\nmaterials: {{m: {material}}}\n"
                                  "spheres: [{center: [0, 0, -1], radius: 0.5, material: m}]\n")
    r = run("render", scene, "-o", tmp_path / "out.npy")
    assert r.returncode == 2 and problem in r.stderr and len(r.stderr.splitlines()) == 1, r.stderr
