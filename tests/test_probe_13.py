"""Hostile probes of issue #13 (textures, motion blur, media): each test is a
defect found by probing, fixed with it or marked xfail with the reason."""

import dataclasses
import math

import numpy as np
import pytest

from wavefront import Box, Camera, Medium, Sphere
from wavefront.shapes import Mesh
from wavefront.transform import Transform

from .test_media import SPP_OF, background_scene, box_mesh_file, rendered, z_score

trimesh = pytest.importorskip("trimesh")

MIRROR = Transform.scale((1, -1, 1))


@pytest.mark.parametrize("kind", ["box", "mesh", "inward mesh"])
@pytest.mark.parametrize("look_from", [(0, 0, 3), (0, 0, 0)])
def test_a_mirrored_boundary_still_holds_its_fog(tmp_path, kind, look_from):
    """A transform with a negative determinant (a mirror) turns a boundary's
    faces inside out in world space; the medium must not turn invisible.
    From outside, a ray through the centre crosses 2 units of absorbing fog;
    from the centre, 1 unit."""
    if kind == "box":
        boundary = Box((-1, -1, -1), (1, 1, 1), 0, MIRROR)
    else:
        boundary = Mesh.read(box_mesh_file(tmp_path, inward=kind == "inward mesh"), 0, transform=MIRROR)
    density = 0.5
    fog = Medium(boundary, density, (0, 0, 0))
    camera = Camera(look_from=look_from, look_at=(0, 0, -5), vfov=2)
    image = rendered(background_scene([fog], camera=camera, spp=64))
    length = 2.0 if look_from[2] == 3 else 1.0
    assert abs(z_score(image, math.exp(-density * length))) < 4.5


def test_a_one_frame_gif_and_a_cmyk_jpeg_are_read_as_rgb(tmp_path):
    """Pillow reads every GIF as a stack of frames ((1, H, W, 3) for one
    frame), which was refused as a bad shape; a CMYK JPEG's four ink
    channels were taken as red, green, blue and alpha."""
    from PIL import Image

    from wavefront.textures import ImageTexture

    rgb = np.zeros((4, 6, 3), dtype=np.uint8)
    rgb[..., 0] = 255  # pure red
    rgb[:2, :, 2] = 255  # magenta on top
    Image.fromarray(rgb).save(tmp_path / "one.gif")
    Image.fromarray(rgb).save(tmp_path / "two.gif", save_all=True, append_images=[Image.fromarray(255 - rgb)])
    Image.fromarray(rgb).convert("CMYK").save(tmp_path / "ink.jpg", quality=100)
    expected = ImageTexture(pixels=rgb.astype(np.float32) / 255).pixels  # red and magenta are 0 or 1 in sRGB too
    for name in ("one.gif", "two.gif"):
        np.testing.assert_array_equal(ImageTexture(str(tmp_path / name)).pixels, expected)
    ink = ImageTexture(str(tmp_path / "ink.jpg")).pixels
    assert ink.shape == (4, 6, 3)
    np.testing.assert_allclose(ink, expected, atol=0.05)  # JPEG is lossy


@pytest.mark.parametrize("kind", ["sphere", "box"])
@pytest.mark.parametrize("offset", [1e-9, 0.0, -1e-9])
def test_a_camera_on_a_boundary_looking_in_sees_the_fog(kind, offset):
    """A camera on a boundary (offset 0), or outside it by less than 1e-6,
    looking in: the boundary lay within the first boundary search's skip
    distance and the camera's point test put it outside, so its rays never
    entered the fog (the image was the bare background).  Every ray crosses
    the 2-unit ball or box of absorbing fog."""
    density = 0.5
    boundary = Sphere((0, 0, 0), 1, 0) if kind == "sphere" else Box((-1, -1, -1), (1, 1, 1), 0)
    fog = Medium(boundary, density, (0, 0, 0))
    camera = Camera(look_from=(0, 0, 1 + offset), look_at=(0, 0, -5), vfov=2)
    image = rendered(background_scene([fog], camera=camera, spp=64))
    assert abs(z_score(image, math.exp(-density * 2.0))) < 4.5


def test_a_moving_sphere_is_refused_as_a_medium_boundary():
    """From Python a Sphere with center1 was accepted as a boundary and its
    motion silently dropped (the fog stayed at ``center``)."""
    from wavefront import SceneError

    with pytest.raises(SceneError, match="boundary.center1"):
        Medium(Sphere((0, 0, 0), 1, 0, center1=(1, 0, 0)), 1.0)
    Medium(Sphere((0, 0, 0), 1, 0), 1.0)  # a still sphere is fine


def test_a_truncated_exr_texture_gives_one_line(tmp_path):
    """OpenEXR's C++ core printed a damaged file's problems on stdout and
    stderr itself: three lines for one bad texture instead of one."""
    import OpenEXR

    from .test_cli import run

    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    pixels = np.random.default_rng(0).random((8, 16, 3)).astype(np.float32)
    with OpenEXR.File(header, {"RGB": pixels}) as exr:
        exr.write(str(tmp_path / "whole.exr"))
    data = (tmp_path / "whole.exr").read_bytes()
    (tmp_path / "cut.exr").write_bytes(data[:len(data) // 2])
    scene = tmp_path / "s.yaml"
    scene.write_text("materials: {m: {type: lambertian, albedo: {type: image, file: cut.exr}}}\n"
                     "spheres: [{center: [0, 0, -1], radius: 0.5, material: m}]\n")
    out = tmp_path / "out.png"
    r = run("render", scene, "-o", out, "--width", 8, "--height", 8, "--spp", 1)
    assert r.returncode == 2 and not out.exists()
    assert r.stdout == ""
    assert len(r.stderr.splitlines()) == 1 and "materials.m.albedo.file" in r.stderr and "cut.exr" in r.stderr


@pytest.mark.parametrize("gap", [1e-7, -1e-7, 1e-12])
def test_fog_just_inside_or_outside_a_glass_ball_is_entered(gap):
    """A fog boundary within 1e-6 of a glass ball's surface but not exactly
    on it (a generated scene's rounding): the boundary was "on the surface"
    before the hit, so not crossed, and skipped after the refraction, so the
    fog vanished (the image was the bare background, 1). With it exactly on
    the glass (the interface case) about 0.17 of the light gets through."""
    from wavefront import Dielectric

    def image(radius):
        fog = Medium(Sphere((0, 0, 0), radius, 0), 1.0, (0, 0, 0))
        scene = background_scene([fog], camera=Camera(look_from=(0, 0, 5), look_at=(0, 0, 0), vfov=5), size=8,
                                 spp=64)
        scene = dataclasses.replace(scene, spheres=[Sphere((0, 0, 0), 1.0, "glass")],
                                    materials={"glass": Dielectric(1.5)})
        return rendered(scene)

    exact = float(image(1.0).mean())
    near = float(image(1.0 + gap).mean())
    assert exact < 0.3
    assert abs(near - exact) < 0.03  # ~3 standard errors of 4096 Bernoulli samples


def test_fog_in_a_mirrored_glass_box_is_entered():
    """A glass box and the same box as a fog boundary, both under a mirror:
    the fog vanished (0.9998, the background) before the mirrored-boundary
    fix; now it matches the unmirrored box within noise (about 0.17)."""
    from wavefront import Dielectric

    def image(transform):
        fog = Medium(Box((-1, -1, -1), (1, 1, 1), 0, transform), 1.0, (0, 0, 0))
        scene = background_scene([fog], camera=Camera(look_from=(0.3, 0.2, 5), look_at=(0, 0, 0), vfov=5),
                                 size=8, spp=64)
        scene = dataclasses.replace(scene, quads=Box((-1, -1, -1), (1, 1, 1), "glass", transform).quads(),
                                    materials={"glass": Dielectric(1.5)})
        return float(rendered(scene).mean())

    plain = image(None)
    assert plain < 0.3
    assert abs(image(MIRROR) - plain) < 0.03


def test_a_transform_sending_center1_out_of_range_names_center1():
    """The message named the (in-range) centre [0, 0, 0] when only center1
    left the coordinate range under the transform."""
    from wavefront import SceneError

    with pytest.raises(SceneError, match=r"centre at time 1 \(center1\) \[1e\+151"):
        Sphere((0, 0, 0), 1, 0, Transform.scale(1e149), center1=(100, 0, 0))
    with pytest.raises(SceneError, match=r"sphere's centre \[1e\+151"):
        Sphere((1e149, 0, 0), 1, 0, Transform.scale(100.0), center1=(0, 0, 0))


@pytest.mark.xfail(reason="a camera exactly on an edge of a mesh boundary: every ray starts on the edge shared by "
                          "two triangles, and the triangle test is not watertight there, so about a fifth of the "
                          "rays find neither triangle and never enter the fog (needs a watertight ray-triangle "
                          "test in the shapes, outside this probe's scope)", strict=True)
def test_a_camera_on_a_mesh_boundary_edge_looking_in_sees_the_fog(tmp_path):
    corners = "".join(f"v {x} {y} {z}\n" for z in (-1, 1) for y in (-1, 1) for x in (-1, 1))
    (tmp_path / "cube.obj").write_text(corners + "f 1 3 4 2\nf 5 6 8 7\nf 1 2 6 5\nf 2 4 8 6\nf 4 3 7 8\nf 3 1 5 7\n")
    density = 2.0
    fog = Medium(Mesh.read(tmp_path / "cube.obj", 0), density, (0, 0, 0))
    camera = Camera(look_from=(0, 0, 1), look_at=(0, 0, -5), vfov=30)  # the +z face's centre: on its diagonal
    image = rendered(background_scene([fog], camera=camera, spp=64))[6:10, 6:10]  # rays crossing the +-z faces
    SPP_OF[id(image)] = 64
    assert abs(z_score(image, math.exp(-density * 2.0))) < 4.5


def test_a_mirrored_emissive_box_lights_its_outside():
    """Boxes' faces are made outward in object space; a mirroring transform
    turned them inward in world space, so an emissive box (one-sided
    emission) went dark from outside. Same root cause as the mirrored fog box."""
    from wavefront import Emissive, RenderSettings, Scene, Solid, render

    def image(transform):
        scene = Scene(quads=Box((-1, -1, -1), (1, 1, 1), "lamp", transform).quads(),
                      materials={"lamp": Emissive((1.0, 1.0, 1.0))}, background=Solid((0.0, 0.0, 0.0)),
                      width=8, height=8, camera=Camera(look_from=(0.5, 0.7, 5), look_at=(0, 0, 0), vfov=10),
                      render=RenderSettings(samples_per_pixel=4, max_depth=2))
        return render(scene, workers=1)

    np.testing.assert_array_equal(image(MIRROR), image(None))
