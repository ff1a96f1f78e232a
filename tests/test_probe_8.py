"""Hostile probes of session 8 (notes/probe8.md): each test is a defect
found by probing the command line, fixed with it."""

import math
import os
import subprocess
import sys
import zlib

import numpy as np
import pytest

from wavefront.output import read_png_metadata

from .test_cli import run

BASE = """image: {width: 16, height: 9}
render: {samples_per_pixel: 1, max_depth: 3}
materials:
  m: {type: lambertian, albedo: [0.5, 0.5, 0.5]}
spheres:
  - {center: [0, 0, -1], radius: 0.5, material: m}
"""
HEAD = "image: {width: 16, height: 9}\nrender: {samples_per_pixel: 1, max_depth: 3}\n"


def run_bytes(*args, cwd=None):
    """The command with arguments that may be bytes (file names that are not UTF-8)."""
    return subprocess.run([sys.executable.encode(), b"-m", b"wavefront", *(a if isinstance(a, bytes) else os.fsencode(str(a)) for a in args)],
                          capture_output=True, cwd=cwd, timeout=300)


def write_scene(tmp_path, text, name="scene.yaml"):
    path = tmp_path / name
    path.write_text(text)
    return path


def refused(r, *needles, outputs=()):
    """Exit status 2, one line naming each needle, no traceback, nothing written."""
    assert r.returncode == 2, r.stderr
    assert "Traceback" not in r.stderr and len(r.stderr.strip().splitlines()) == 1, r.stderr
    for needle in needles:
        assert needle in r.stderr, r.stderr
    for out in outputs:
        assert not os.path.exists(out), out


def png_chunks(path):
    data = open(path, "rb").read()
    pos, chunks = 8, []
    while pos < len(data):
        (length,), kind = np.frombuffer(data[pos:pos + 4], ">u4"), data[pos + 4:pos + 8]
        chunks.append((kind, data[pos + 8:pos + 8 + int(length)]))
        pos += 12 + int(length)
    return chunks


# --- 1: a scene whose path is not UTF-8 --------------------------------------

@pytest.mark.parametrize("ext", ["png", "exr", "npy"])
def test_a_scene_path_that_is_not_utf8_renders_to_every_format(tmp_path, ext):
    folder = os.path.join(os.fsencode(tmp_path), b"\xffdir")
    os.mkdir(folder)
    with open(os.path.join(folder, b"\xff\xfe.yaml"), "w") as f:
        f.write(BASE)
    out = os.path.join(folder, b"\xfeout." + ext.encode())
    ck = os.path.join(folder, b"\xfeck.npz")
    r = run_bytes("render", os.path.join(folder, b"\xff\xfe.yaml"), "-o", out, "--checkpoint", ck, "-q")
    assert r.returncode == 0 and r.stderr == b"", r.stderr
    assert os.path.exists(out) and os.path.exists(ck)
    if ext == "png":
        assert read_png_metadata(os.fsdecode(out))["wavefront.scene"] == "\\xff\\xfe"
    again = os.path.join(folder, b"again.npy")
    r = run_bytes("render", os.path.join(folder, b"\xff\xfe.yaml"), "-o", again, "--resume", ck, "-q")
    assert r.returncode == 0, r.stderr


def test_texture_and_mesh_paths_that_are_not_utf8_reach_the_checkpoint(tmp_path):
    folder = os.path.join(os.fsencode(tmp_path), b"\xffdir")
    os.mkdir(folder)
    import imageio.v3 as iio

    iio.imwrite(os.fsdecode(os.path.join(folder, b"tiny.png")), np.full((2, 2, 3), 128, np.uint8))
    with open(os.path.join(folder, b"tri.obj"), "w") as f:
        f.write("v 0 0 -2\nv 1 0 -2\nv 0 1 -2\nf 1 2 3\n")
    with open(os.path.join(folder, b"scene.yaml"), "w") as f:
        f.write(HEAD + "materials: {m: {type: lambertian, albedo: {type: image, file: tiny.png}}}\n"
                "spheres: [{center: [0,0,-1], radius: 0.5, material: m}]\nmeshes: [{file: tri.obj, material: m}]\n")
    r = run_bytes("render", os.path.join(folder, b"scene.yaml"), "-o", os.path.join(folder, b"x.npy"),
                  "--checkpoint", os.path.join(folder, b"ck.npz"), "-q")
    assert r.returncode == 0, r.stderr


def test_an_encoder_failing_after_the_render_does_not_lose_the_image(tmp_path, monkeypatch, capsys):
    from wavefront import cli, output

    def broken(f, image, metadata):
        raise ValueError("the encoder broke")

    monkeypatch.setattr(output, "_write_png", broken)
    monkeypatch.setattr("tempfile.tempdir", str(tmp_path))
    scene = write_scene(tmp_path, BASE)
    status = cli.main(["render", str(scene), "-o", str(tmp_path / "x.png"), "-q", "--workers", "1"])
    err = capsys.readouterr().err
    assert status == 2 and "the encoder broke" in err and "saved to" in err, err
    rescued = list(tmp_path.glob("wavefront-rescued-*.npy"))
    assert len(rescued) == 1 and np.load(rescued[0]).shape == (9, 16, 3)


# --- 16: PNG text chunks ------------------------------------------------------

def test_png_text_holds_no_nul_and_unicode_goes_to_itxt(tmp_path):
    scene = write_scene(tmp_path, 'name: "a\\nb\\u0000c \\u00e9\\u20ac"\n' + BASE)
    out = tmp_path / "x.png"
    r = run("render", scene, "-o", out, "-q")
    assert r.returncode == 0, r.stderr
    for kind, data in png_chunks(out):
        if kind == b"tEXt":
            key, _, text = data.partition(b"\0")
            assert b"\0" not in text
            text.decode("latin-1")
        elif kind == b"iTXt":
            key, _, rest = data.partition(b"\0")
            text = rest[2:].split(b"\0", 2)[2]
            assert b"\0" not in text
            text.decode("utf-8")
    assert read_png_metadata(out)["wavefront.scene"] == "a\nb\\x00c \u00e9\u20ac"


# --- 3: huge media boundaries ---------------------------------------------------

MEDIA_HEAD = HEAD + "materials: {m: {type: lambertian}}\n"


@pytest.mark.parametrize("sphere", ["{center: [0,0,0], radius: 1e120}",
                                    "{center: [0,0,0], radius: 1e50, transform: [{scale: 1e60}]}"])
def test_a_medium_sphere_beyond_float64_volume_renders(tmp_path, sphere):
    scene = write_scene(tmp_path, MEDIA_HEAD + f"media: [{{boundary: {{sphere: {sphere}}}, density: 0.01}}]\n")
    r = run("render", scene, "-o", tmp_path / "x.npy", "-q", "--workers", 1)
    assert r.returncode == 0 and r.stderr == "", r.stderr
    assert np.isfinite(np.load(tmp_path / "x.npy")).all()


@pytest.mark.parametrize("extent,problem", [("1e80", "box too large: a face's area squared overflows"),
                                            ("1e150", "box too large: an edge (max - min) must be <= 1e+150")])
def test_a_huge_medium_box_is_refused_at_load_naming_its_yaml_path(tmp_path, extent, problem):
    scene = write_scene(tmp_path, MEDIA_HEAD + f"media: [{{boundary: {{box: {{min: [-{extent}, -{extent}, "
                                               f"-{extent}], max: [{extent}, {extent}, {extent}]}}}}, density: 0.01}}]\n")
    r = run("render", scene, "-o", tmp_path / "x.npy")
    refused(r, "scene.yaml: media[0].boundary.box: " + problem, outputs=[tmp_path / "x.npy"])


def test_media_order_by_volume_survives_overflow_and_keeps_its_order():
    from wavefront import Box, Medium, Sphere
    from wavefront.media import boundary_log_volume, boundary_volume, volume_order
    from wavefront.shapes import Mesh

    trimesh = pytest.importorskip("trimesh")
    cube = trimesh.creation.box(bounds=[(-1, -2, -3), (2, 1, 1)])
    small = [Medium(Sphere((0, 0, 0), 2.5, 0), 1.0), Medium(Box((0, 0, 0), (1, 2, 3), 0, [{"scale": 2}]), 1.0),
             Medium(Mesh(np.asarray(cube.vertices), np.asarray(cube.faces), 0, transform=[{"scale": 3}]), 1.0)]
    for m in small:  # the logarithm agrees with the volume
        assert boundary_log_volume(m) == pytest.approx(np.log(boundary_volume(m)), rel=1e-12)
    np.testing.assert_array_equal(volume_order(small), [boundary_volume(m) for m in small])
    huge = small + [Medium(Sphere((0, 0, 0), 1e120, 0), 1.0), Medium(Sphere((0, 0, 0), 1e110, 0), 1.0)]
    keys = volume_order(huge)
    assert np.isfinite(keys).all() and list(np.argsort(keys)) == [1, 0, 2, 4, 3]  # 48, 65, 972, 4e330, 4e360


def test_the_api_renders_a_huge_medium_sphere():
    from wavefront import Camera, Lambertian, Medium, RenderSettings, Scene, Sphere, render

    scene = Scene(materials={"m": Lambertian((0.5, 0.5, 0.5))}, width=4, height=4,
                  camera=Camera(look_from=(0, 0, 0), look_at=(0, 0, -1)),
                  render=RenderSettings(samples_per_pixel=1, max_depth=2),
                  media=[Medium(Sphere((0, 0, 0), 1e120, 0), 0.01)])
    assert np.isfinite(render(scene, workers=1)).all()


# --- 10: huge boxes -------------------------------------------------------------

@pytest.mark.parametrize("extent,problem", [("1e100", "box too large: a face's area squared overflows"),
                                            ("1e150", "box too large: an edge (max - min) must be <= 1e+150")])
def test_a_huge_box_is_refused_naming_the_file_and_its_yaml_path(tmp_path, extent, problem):
    scene = write_scene(tmp_path, MEDIA_HEAD + "boxes: [{min: [0, 0, 0], max: [1, 1, 1], material: m}, "
                                               f"{{min: [-{extent}, -{extent}, -{extent}], max: [{extent}, {extent}, "
                                               f"{extent}], material: m}}]\n")
    r = run("render", scene, "-o", tmp_path / "x.npy")
    refused(r, "scene.yaml: boxes[1]: " + problem, outputs=[tmp_path / "x.npy"])


# --- 4: every frame checked before the first is rendered --------------------------

def test_a_frame_whose_camera_leaves_the_range_is_refused_before_any_frame_is_written(tmp_path):
    scene = write_scene(tmp_path, HEAD + "materials: {m: {type: lambertian}}\n"
                        "camera: {look_from: [-1e150, 0, 0], look_at: [1e150, 0, 0]}\n"
                        "spheres: [{center: [1e150, 0, 0], radius: 1e149, material: m}]\n")
    r = run("render", scene, "-o", tmp_path / "f_{frame}.png", "--frames", 2)
    refused(r, "scene.yaml: camera.look_from[0]: in frame 1 of --frames 2", outputs=[tmp_path / "f_0.png"])


@pytest.mark.parametrize("render,camera,sphere,needle", [
    # review8 #5: a scene-level problem of a turned frame keeps its own YAML path
    ("precision: float32", "look_from: [0, 0, 0], look_at: [6e17, 0, 0]", "center: [6e17, 0, 0], radius: 1e17",
     "scene.yaml: render.precision: in frame 1 of --frames 2"),
    # the scene's check of the camera names the camera's path once
    ("max_depth: 3", "look_from: [0, 0, 0], look_at: [7e11, 0, 0], focus_dist: 3e-3",
     "center: [7e11, 0, 0], radius: 1e11", "scene.yaml: camera.look_at: in frame 1 of --frames 2"),
])
def test_a_frames_problem_is_named_by_its_own_yaml_path(tmp_path, render, camera, sphere, needle):
    scene = write_scene(tmp_path, "image: {width: 16, height: 9}\n"
                        f"render: {{samples_per_pixel: 1, {render}}}\ncamera: {{{camera}}}\n"
                        f"materials: {{m: {{type: lambertian}}}}\nspheres: [{{{sphere}, material: m}}]\n")
    r = run("render", scene, "-o", tmp_path / "f_{frame}.npy", "--frames", 2)
    refused(r, needle, outputs=[tmp_path / "f_0.npy"])
    assert "camera.render" not in r.stderr and "camera.camera" not in r.stderr


# --- 6: camera vectors of any scale -------------------------------------------------

def camera_image(**camera):
    from wavefront import render
    from wavefront.scenefile import scene_from_dict
    import yaml

    doc = yaml.safe_load(BASE)
    doc["camera"] = camera
    return render(scene_from_dict(doc), workers=1)


@pytest.mark.filterwarnings("error")
@pytest.mark.parametrize("camera,same_as", [
    ({"vup": [0, 1e200, 0]}, {"vup": [0, 1, 0]}),
    ({"vup": [0, 1e-200, 0]}, {"vup": [0, 1, 0]}),
    ({"look_at": [0, 0, -1e-200], "focus_dist": 1}, {"look_at": [0, 0, -1], "focus_dist": 1}),
])
def test_huge_or_tiny_camera_vectors_give_the_image_of_unit_ones(camera, same_as):
    image = camera_image(**camera)
    assert image.mean() > 0.1
    np.testing.assert_array_equal(image, camera_image(**same_as))


def test_a_turntable_with_a_tiny_vup_renders_every_frame(tmp_path):
    scene = write_scene(tmp_path, HEAD + "materials: {m: {type: lambertian}}\n"
                        "camera: {look_from: [0, 0, 1], look_at: [0, 0, 0], vup: [0, 1e-300, 0]}\n"
                        "spheres: [{center: [0, 0, 0], radius: 0.5, material: m}]\n")
    r = run("render", scene, "-o", tmp_path / "g_{frame}.npy", "--frames", 4, "-q")
    assert r.returncode == 0 and r.stderr == "", r.stderr
    assert all(np.load(tmp_path / f"g_{k}.npy").mean() > 0.1 for k in range(4))


@pytest.mark.filterwarnings("error")
@pytest.mark.parametrize("distance", [1e-141, 1e-145, 1e-150, 1.01 * 4.5 * math.sqrt(np.finfo(np.float64).tiny)])
def test_a_tiny_view_whose_squares_stay_normal_gives_the_image_of_a_unit_one(distance):
    # review8 #4: 1e-140 refused views float64 renders exactly; the bound is
    # where a pixel's square leaves the normal numbers (16x9 at vfov 90: a
    # pixel is 2 distance / 9 wide, so the last case is 1 % above the bound)
    image = camera_image(look_from=[0, 0, 0], look_at=[0, 0, -distance])
    assert image.mean() > 0.1
    np.testing.assert_array_equal(image, camera_image(look_from=[0, 0, 0], look_at=[0, 0, -1]))


@pytest.mark.parametrize("distance", [0.99 * 4.5 * math.sqrt(np.finfo(np.float64).tiny), 1e-155, 1e-158])
def test_a_view_whose_pixel_squares_underflow_is_refused(distance):
    from wavefront.camera import MIN_PIXEL
    from wavefront.validation import SceneError

    assert MIN_PIXEL ** 2 >= np.finfo(np.float64).tiny > (0.99 * MIN_PIXEL) ** 2
    with pytest.raises(SceneError, match="camera.look_at: the view is too small"):
        camera_image(look_from=[0, 0, 0], look_at=[0, 0, -distance])


def test_a_view_too_small_for_float64_is_refused():
    from wavefront import Camera, Scene, Sphere, Lambertian
    from wavefront.validation import SceneError

    with pytest.raises(SceneError, match="camera.look_at: the view is too small"):
        Scene(materials={"m": Lambertian((0.5, 0.5, 0.5))}, spheres=[Sphere((0, 0, -1), 0.5, "m")],
              camera=Camera(look_at=(0, 0, -1e-200)))


# --- 5: material names in a scene file are strings -----------------------------------

@pytest.mark.parametrize("shapes,path,got", [
    ("spheres: [{center: [0, 0, -1], radius: 0.5, material: 1}]", "spheres[0].material", "integer 1"),
    ("spheres: [{center: [0, 0, -1], radius: 0.5, material: m}, {center: [0, 0, -1], radius: 0.5, material: 0, "
     "transform: []}]", "spheres[1].material", "integer 0"),
    ("quads: [{corner: [0, 0, -1], u: [1, 0, 0], v: [0, 1, 0], material: 0}]", "quads[0].material", "integer 0"),
    ("boxes: [{min: [0, 0, -2], max: [1, 1, -1], material: 0.5}]", "boxes[0].material", "number 0.5"),
    ("meshes: [{file: tri.obj, material: 0}]", "meshes[0].material", "integer 0"),
])
def test_a_material_given_as_a_number_is_refused(tmp_path, shapes, path, got):
    (tmp_path / "tri.obj").write_text("v 0 0 -2\nv 1 0 -2\nv 0 1 -2\nf 1 2 3\n")
    scene = write_scene(tmp_path, HEAD + 'materials: {m: {type: lambertian}, "1": {type: metal}}\n' + shapes + "\n")
    r = run("render", scene, "-o", tmp_path / "x.npy")
    refused(r, f"scene.yaml: {path}: expected a material name (a string), got {got}", outputs=[tmp_path / "x.npy"])


def test_a_quoted_number_names_the_material():
    from wavefront.scenefile import read_yaml, scene_from_dict

    scene = scene_from_dict(read_yaml(HEAD.encode() + b'materials: {m: {type: lambertian}, "1": {type: metal}}\n'
                                      b'spheres: [{center: [0, 0, -1], radius: 0.5, material: "1"}]\n', "q.yaml"))
    assert scene.spheres[0].material == "1"


# --- 14: an aliased list is not emptied ------------------------------------------------

def test_an_alias_of_the_spheres_list_still_sees_its_entries(tmp_path):
    scene = write_scene(tmp_path, HEAD + "materials: {m: {type: lambertian}}\n"
                        "spheres: &l [{center: [0, 0, -1], radius: 0.5, material: m}]\nquads: *l\n")
    r = run("render", scene, "-o", tmp_path / "x.npy")
    refused(r, "scene.yaml: quads[0].center: unknown key", outputs=[tmp_path / "x.npy"])


def test_an_unshared_spheres_list_is_still_let_go_while_the_spheres_are_built(monkeypatch, tmp_path):
    import wavefront.scenefile as scenefile

    lists = []

    class Spy:  # sys, recording the list whose references are counted
        def __getattr__(self, name):
            return getattr(sys, name)

        def getrefcount(self, value):
            count = sys.getrefcount(value) - 1  # less this frame's own reference
            lists.append(value)
            return count

    monkeypatch.setattr(scenefile, "sys", Spy())
    scene = scenefile.load_scene(write_scene(tmp_path, BASE))
    assert len(scene.spheres) == 1 and lists == [[]]  # cleared while the spheres were built
    scenefile.load_scene(write_scene(tmp_path, BASE.replace("spheres:", "spheres: &l") + "quads: []\n", "a.yaml"))
    assert lists[1] == []  # an anchor no alias uses shares nothing


# --- 11: stale temporary files -------------------------------------------------------

def test_a_refused_command_removes_nothing_and_only_wavefronts_own_names_go(tmp_path):
    import time

    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()
    old = time.time() - 3600
    notes = tmp_path / f".wavefront-{dead.pid}-my-notes.txt"
    stale = tmp_path / f".wavefront-{dead.pid}-abcd_123.png"
    for p in (notes, stale):
        p.write_bytes(b"x")
        os.utime(p, (old, old))
    empty = write_scene(tmp_path, "", "empty.yaml")
    r = run("render", empty, "-o", tmp_path / "x.png")
    refused(r, "empty.yaml: the file is empty")
    assert notes.exists() and stale.exists()  # refused: nothing changed
    r = run("render", write_scene(tmp_path, BASE), "-o", tmp_path / "x.png", "-q")
    assert r.returncode == 0, r.stderr
    assert notes.exists() and not stale.exists()


# --- 17: a scene read from a pipe resolves relative paths against the current directory --

def test_a_piped_scene_reads_its_mesh_relative_to_the_current_directory(tmp_path):
    (tmp_path / "tri.obj").write_text("v 0 0 -2\nv 1 0 -2\nv 0 1 -2\nf 1 2 3\n")
    text = HEAD + "materials: {m: {type: lambertian}}\nmeshes: [{file: tri.obj, material: m}]\n"
    r = subprocess.run([sys.executable, "-m", "wavefront", "render", "/dev/stdin", "-o", "x.npy", "-q"],
                       input=text, capture_output=True, text=True, cwd=tmp_path, timeout=300)
    assert r.returncode == 0, r.stderr
    assert (tmp_path / "x.npy").exists()


def test_relative_paths_of_a_regular_scene_file_stay_relative_to_its_directory(tmp_path):
    from wavefront.scenefile import _relative_to

    assert _relative_to("scenes/a.yaml") == "scenes" and _relative_to("scenes/fifo.yaml") == "scenes"
    assert _relative_to("/dev/stdin") == "" and _relative_to("/dev/fd/63") == ""
    assert _relative_to("/proc/self/fd/0") == "" and _relative_to("/proc/123/task/124/fd/7") == ""
    # only a path naming a descriptor: other files in /dev or /proc keep their directory
    assert _relative_to("/dev/shm/a.yaml") == "/dev/shm" and _relative_to("/dev/fd/x.yaml") == "/dev/fd"


def test_a_scene_in_a_named_fifo_reads_its_mesh_and_texture_relative_to_its_directory(tmp_path):
    import imageio.v3 as iio

    folder = tmp_path / "fifo"
    folder.mkdir()
    (folder / "tri.obj").write_text("v -1 -1 -2\nv 1 -1 -2\nv 0 1 -2\nf 1 2 3\n")
    iio.imwrite(folder / "tiny.png", np.full((2, 2, 3), 200, np.uint8))
    os.mkfifo(folder / "s.yaml")
    text = HEAD + ("materials: {m: {type: lambertian, albedo: {type: image, file: tiny.png}}}\n"
                   "meshes: [{file: tri.obj, material: m}]\n")
    # cwd is tmp_path, where neither file is: they must be found next to the FIFO
    command = subprocess.Popen([sys.executable, "-m", "wavefront", "render", "fifo/s.yaml", "-o", "f.npy", "-q"],
                               cwd=tmp_path, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    import time

    while command.poll() is None:  # until the command opens the FIFO to read (not forever if it fails first)
        try:
            fd = os.open(folder / "s.yaml", os.O_WRONLY | os.O_NONBLOCK)
        except OSError:  # ENXIO: no reader yet
            time.sleep(0.02)
            continue
        os.set_blocking(fd, True)
        with open(fd, "w") as f:
            f.write(text)
        break
    _, err = command.communicate(timeout=300)
    assert command.returncode == 0, err
    assert (tmp_path / "f.npy").exists()


# --- 13: a pipe is read in chunks against the budget ---------------------------------

def test_a_pipe_over_the_budget_is_refused_before_it_is_read_whole(monkeypatch, tmp_path):
    import io

    from wavefront.memory import MemoryBudgetError
    from wavefront import scenefile

    class Endless(io.RawIOBase):  # a pipe that never ends: counts what is read
        given = 0

        def readable(self):
            return True

        def readinto(self, b):
            b[:] = b"#" * len(b)
            Endless.given += len(b)
            return len(b)

    with pytest.raises(MemoryBudgetError, match="read so far"):
        scenefile._read_stream(io.BufferedReader(Endless()), "/dev/stdin", 64 << 20)
    assert Endless.given < 16 * scenefile.STREAM_CHUNK  # a 64 MiB budget holds a few MiB of YAML, not 128 MiB


def test_a_pipe_counts_the_bytes_it_has_read_once(monkeypatch):
    """What has been read is already in this process's memory: the check
    adds what loading it will take on top (as for a file, checked before it
    is read), not the bytes read a second time.  A 19 MiB scene that loaded
    from a file under --memory 200M was refused through /dev/stdin."""
    import io

    from wavefront import memory, scenefile

    class Pipe(io.RawIOBase):  # SIZE bytes of comment, then the end
        given = 0

        def readable(self):
            return True

        def readinto(self, b):
            n = min(len(b), SIZE - Pipe.given)
            b[:n] = b"#" * n
            Pipe.given += n
            return n

    SIZE, start = 8 * scenefile.STREAM_CHUNK, 40 << 20
    # this process as it would be: what it held before reading plus the bytes read
    monkeypatch.setattr(memory, "current_rss", lambda: start + Pipe.given)
    budget = start + memory.LOAD_BYTES_PER_FILE_BYTE * SIZE  # exactly what a file of SIZE bytes may take
    assert len(scenefile._read_stream(io.BufferedReader(Pipe()), "/dev/stdin", budget)) == SIZE
    Pipe.given = 0
    with pytest.raises(memory.MemoryBudgetError, match=r"loading /dev/stdin \(8 MiB read so far\) needs about "
                                                       r"56 MiB more than the 48 MiB this process holds"):
        scenefile._read_stream(io.BufferedReader(Pipe()), "/dev/stdin", budget - 1)


def test_dev_zero_is_refused_within_the_budget(tmp_path):
    r = run("render", "/dev/zero", "-o", tmp_path / "x.npy", "--memory", "64M")
    refused(r, "/dev/zero", "--memory", outputs=[tmp_path / "x.npy"])


# --- 12: the temporary file is on disk before it is renamed -----------------------------

def test_images_and_checkpoints_are_synced_before_the_rename(tmp_path, monkeypatch):
    from wavefront import output
    from wavefront.film import Film, save_checkpoint
    from wavefront.scenefile import load_scene

    events = []
    real_fsync, real_replace = os.fsync, os.replace
    monkeypatch.setattr(os, "fsync", lambda fd: (events.append(("fsync", os.readlink(f"/proc/self/fd/{fd}"))),
                                                 real_fsync(fd)))
    monkeypatch.setattr(os, "replace", lambda a, b: (events.append(("replace", str(a))), real_replace(a, b)))
    image = np.full((2, 3, 3), 0.5, np.float32)
    for ext in ("png", "exr", "npy"):
        output.write_image(str(tmp_path / f"x.{ext}"), image)
    scene = load_scene(write_scene(tmp_path, BASE))
    save_checkpoint(str(tmp_path / "ck.npz"), scene, Film(scene.width, scene.height), 0)
    renames = [i for i, e in enumerate(events) if e[0] == "replace"]
    assert len(renames) == 4
    for i in renames:
        assert events[i - 1] == ("fsync", events[i][1]), events  # the temporary file itself, just before


# --- review8 #2: durability never costs the image -------------------------------------------

def _owner_only_dac(real_open):
    """``os.open`` as the kernel checks it for a process without CAP_DAC_OVERRIDE
    (root in a container that dropped it, or any user on their own file): the
    owner's read/write bits decide."""
    import errno
    import stat

    def checked(path, flags, *args, **kwargs):
        try:
            st = os.stat(path)
        except OSError:
            return real_open(path, flags, *args, **kwargs)
        if stat.S_ISREG(st.st_mode):
            access = flags & os.O_ACCMODE
            need = {os.O_RDONLY: stat.S_IRUSR, os.O_WRONLY: stat.S_IWUSR}.get(access, stat.S_IRUSR | stat.S_IWUSR)
            if st.st_mode & need != need:
                raise PermissionError(errno.EACCES, os.strerror(errno.EACCES), path)
        return real_open(path, flags, *args, **kwargs)
    return checked


@pytest.mark.parametrize("ext", ["png", "exr", "npy"])
def test_an_image_whose_mode_has_no_read_bit_is_still_written_and_synced(tmp_path, monkeypatch, ext):
    from wavefront import output

    synced = []
    real_fsync = os.fsync
    monkeypatch.setattr(os, "open", _owner_only_dac(os.open))
    monkeypatch.setattr(os, "fsync", lambda fd: (synced.append(os.readlink(f"/proc/self/fd/{fd}")), real_fsync(fd)))
    image = np.full((2, 3, 3), 0.5, np.float32)
    kept = tmp_path / f"kept.{ext}"  # an existing write-only file: its mode carries over
    kept.write_bytes(b"old")
    os.chmod(kept, 0o200)
    output.write_image(str(kept), image)
    assert os.stat(kept).st_mode & 0o777 == 0o200 and kept.read_bytes() != b"old"
    old = os.umask(0o477)
    try:
        output.write_image(str(tmp_path / f"new.{ext}"), image)
    finally:
        os.umask(old)
    assert os.stat(tmp_path / f"new.{ext}").st_mode & 0o777 == 0o200
    assert sum(".wavefront-" in p for p in synced) == 2, synced  # each temporary file, before its rename


def test_a_checkpoint_whose_mode_has_no_read_bit_is_still_written(tmp_path, monkeypatch):
    from wavefront.film import Film, save_checkpoint
    from wavefront.scenefile import load_scene

    scene = load_scene(write_scene(tmp_path, BASE))
    monkeypatch.setattr(os, "open", _owner_only_dac(os.open))
    old = os.umask(0o477)
    try:
        save_checkpoint(str(tmp_path / "ck.npz"), scene, Film(scene.width, scene.height), 0)
    finally:
        os.umask(old)
    assert os.stat(tmp_path / "ck.npz").st_mode & 0o777 == 0o200


@pytest.mark.skipif(os.geteuid() != 0 or not os.path.exists("/usr/bin/setpriv"),
                    reason="needs root and setpriv to drop CAP_DAC_OVERRIDE")
def test_the_command_under_umask_0477_without_dac_override_writes_its_image(tmp_path):
    scene = write_scene(tmp_path, BASE)
    r = subprocess.run(["setpriv", "--bounding-set=-dac_override,-dac_read_search,-fowner", "--inh-caps=-all",
                        "sh", "-c", f'umask 0477; exec "{sys.executable}" -m wavefront render scene.yaml '
                        '-o o.png --checkpoint ck.npz -q'], capture_output=True, text=True, cwd=tmp_path,
                       timeout=300)
    assert r.returncode == 0 and r.stderr == "", r.stderr
    assert os.path.getsize(tmp_path / "o.png") > 0 and os.path.getsize(tmp_path / "ck.npz") > 0


# --- 15: image textures within the colour limit ------------------------------------------

@pytest.mark.parametrize("value,use", [(3e38, "emissive, color"), (1e31, "lambertian, albedo")])
def test_an_exr_texture_beyond_the_colour_limit_is_refused_naming_the_file(tmp_path, value, use):
    import OpenEXR

    kind, key = use.split(", ")
    pixels = np.full((2, 2, 3), value, np.float32)
    with OpenEXR.File({"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage},
                      {"RGB": pixels}) as exr:
        exr.write(str(tmp_path / "hot.exr"))
    scene = write_scene(tmp_path, HEAD + f"materials: {{m: {{type: {kind}, {key}: {{type: image, file: hot.exr}}}}}}\n"
                                         "spheres: [{center: [0, 0, -1], radius: 0.5, material: m}]\n")
    r = run("render", scene, "-o", tmp_path / "x.npy")
    refused(r, f"scene.yaml: materials.m.{key}.file: ", "hot.exr: the image holds values up to",
            "a colour is at most 1e+30", outputs=[tmp_path / "x.npy"])


def test_pixels_given_in_python_are_held_to_the_colour_limit():
    from wavefront.textures import ImageTexture
    from wavefront.validation import SceneError

    with pytest.raises(SceneError, match="at most 1e"):
        ImageTexture(pixels=np.full((1, 1, 3), 1e31, np.float32))
    assert ImageTexture(pixels=np.full((1, 1, 3), 1e30, np.float32)).pixels.max() == np.float32(1e30)


# --- 8: a forced float32 that cannot hold the scene ---------------------------------------

@pytest.mark.parametrize("spheres,needle", [
    ("[{center: [0, 0, -1e39], radius: 3e38, material: m}]", "it reaches 1.3e+39 from the origin"),
    ("[{center: [0, 0, -1], radius: 1e-20, material: m}]", "a sphere's radius is 1e-20"),
])
def test_forced_float32_beyond_its_range_is_refused_in_one_line(tmp_path, spheres, needle):
    scene = write_scene(tmp_path, "image: {width: 16, height: 9}\n"
                                  "render: {samples_per_pixel: 1, max_depth: 3, precision: float32}\n"
                                  "background: {type: solid, color: [1, 1, 1]}\n"
                                  "materials: {m: {type: lambertian, albedo: [0, 0, 0]}}\n"
                                  f"spheres: {spheres}\n")
    r = run("render", scene, "-o", tmp_path / "x.npy")
    refused(r, "scene.yaml: render.precision: float32 cannot hold this scene", needle, outputs=[tmp_path / "x.npy"])


# --- 19: messages ---------------------------------------------------------------------------

def test_a_budget_refused_while_compiling_names_the_scene(tmp_path, monkeypatch, capsys):
    from wavefront import cli
    from wavefront.memory import MemoryBudgetError

    render = sys.modules["wavefront.render"]  # the module (the package's ``render`` is the function)

    def refuse(scene, memory):
        raise MemoryBudgetError("compiling 405,000 primitives needs about 300 MiB more than ...")

    monkeypatch.setattr(render, "compile_within", refuse)
    scene = write_scene(tmp_path, BASE)
    status = cli.main(["render", str(scene), "-o", str(tmp_path / "x.npy"), "--workers", "1"])
    err = capsys.readouterr().err
    assert status == 2 and err.startswith(f"wavefront: error: {scene}: compiling 405,000 primitives"), err
    assert err.rstrip().endswith("(--memory)") and not (tmp_path / "x.npy").exists()


def png_header(path, width, height):
    def chunk(kind, data):
        return len(data).to_bytes(4, "big") + kind + data + zlib.crc32(kind + data).to_bytes(4, "big")

    ihdr = width.to_bytes(4, "big") + height.to_bytes(4, "big") + bytes([8, 2, 0, 0, 0])
    path.write_bytes(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", zlib.compress(b"\0" * 100))
                     + chunk(b"IEND", b""))


@pytest.mark.parametrize("width,height", [(20000, 10000), (10000, 10000)])  # past Pillow's error, past its warning
def test_a_huge_png_texture_gets_wavefronts_own_one_line(tmp_path, width, height):
    png_header(tmp_path / "big.png", width, height)
    scene = write_scene(tmp_path, HEAD + "materials: {m: {type: lambertian, albedo: {type: image, file: big.png}}}\n"
                                         "spheres: [{center: [0, 0, -1], radius: 0.5, material: m}]\n")
    r = run("render", scene, "-o", tmp_path / "x.npy")
    refused(r, f"scene.yaml: materials.m.albedo.file: ", f"big.png: the image is {width}x{height}",
            outputs=[tmp_path / "x.npy"])
    assert "bomb" not in r.stderr


def test_a_frame_pattern_that_makes_no_file_name_names_the_flag(tmp_path):
    r = run("render", write_scene(tmp_path, BASE), "-o", tmp_path / "x{frame:c}.png", "--frames", 55297)
    refused(r, "the {frame} pattern makes frame 55296's file name", "--frames")
    assert not list(tmp_path.glob("x*.png"))
