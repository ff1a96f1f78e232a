"""Textures: the checker's parity, image lookups and decoding, Perlin marble, and bad input."""

import math
import struct
import subprocess
import sys
import zlib

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from wavefront import Camera, Lambertian, Scene, Sphere, load_scene, render
from wavefront.materials import Emissive, MaterialTable, Metal
from wavefront.textures import (MAX_TEXTURE_PIXELS, Checker, ImageTexture, Noise, Perlin, TextureTable, lookup,
                                texture_field)
from wavefront.validation import SceneError

from .test_furnace import SCENES
from .test_fuzz import BAD_VALUES, paths

EVEN, ODD = (0.2, 0.3, 0.1), (0.9, 0.9, 0.9)
coordinate = st.floats(-1e3, 1e3, allow_nan=False)


def evaluate(texture, points, uv=None):
    table = TextureTable()
    node = table.add(texture)
    points = np.asarray(points, dtype=np.float64).reshape(3, -1)
    return table.evaluate(np.full(points.shape[1], node), points, uv)


def book_parity_even(p, scale):
    """RTOW's checker_texture::value, point by point in plain Python."""
    return sum(math.floor(x / scale) for x in p) % 2 == 0


def truncating_parity_even(p, scale):
    """A wrong checker (int() truncates towards zero): one cube too wide at every axis' zero."""
    return sum(int(x / scale) for x in p) % 2 == 0


# -- checker ---------------------------------------------------------------

@settings(max_examples=200, deadline=None)
@given(st.lists(st.tuples(coordinate, coordinate, coordinate), min_size=1, max_size=50),
       st.floats(0.01, 10.0))
def test_checker_parity_matches_the_book_on_any_points(points, scale):
    colors = evaluate(Checker(scale, EVEN, ODD), np.array(points).T)
    for p, c in zip(points, colors.T):
        assert tuple(c) == (EVEN if book_parity_even(p, scale) else ODD), (p, scale)


def test_checker_negative_control_truncation_is_caught():
    """Near the planes through 0 the truncating checker differs; the table agrees with floor, not it."""
    points = [(-0.1, 0.05, 0.05), (0.05, -0.7, 2.2), (-1.5, -0.5, 0.3)]
    assert any(book_parity_even(p, 1.0) != truncating_parity_even(p, 1.0) for p in points)
    colors = evaluate(Checker(1.0, EVEN, ODD), np.array(points).T)
    for p, c in zip(points, colors.T):
        assert tuple(c) == (EVEN if book_parity_even(p, 1.0) else ODD)
        if book_parity_even(p, 1.0) != truncating_parity_even(p, 1.0):
            assert tuple(c) != (EVEN if truncating_parity_even(p, 1.0) else ODD)


def test_nested_checkers_resolve_level_by_level():
    inner = Checker(0.5, (1.0, 0.0, 0.0), (0.0, 0.0, 1.0))
    outer = Checker(2.0, inner, (0.0, 1.0, 0.0))
    points = np.array([[0.1, 0.1, 0.1], [0.6, 0.1, 0.1], [2.5, 0.1, 0.1]]).T
    colors = evaluate(outer, points)
    np.testing.assert_array_equal(colors.T, [[1, 0, 0], [0, 0, 1], [0, 1, 0]])


# -- images ----------------------------------------------------------------

def write_png(path, pixels):
    import imageio.v3 as iio

    iio.imwrite(path, np.asarray(pixels, dtype=np.uint8))
    return str(path)


# 2 rows x 3 columns; row 0 is the top of the picture
TINY = np.array([[[255, 0, 0], [0, 255, 0], [0, 0, 255]],
                 [[10, 20, 30], [128, 128, 128], [255, 255, 255]]], dtype=np.uint8)


def test_8bit_images_are_decoded_from_srgb_with_colour_science(tmp_path):
    import colour

    texture = ImageTexture(write_png(tmp_path / "tiny.png", TINY))
    expected = colour.cctf_decoding(TINY / 255.0, function="sRGB")
    np.testing.assert_allclose(texture.pixels, expected, rtol=1e-6, atol=1e-7)
    assert texture.pixels[1, 1, 0] == pytest.approx(0.2158605, abs=1e-6)  # 128: not 128/255 = 0.502


def test_the_8bit_decoding_table_is_colour_sciences_bit_for_bit(tmp_path):
    """The shipped table (an 8-bit texture is decoded without importing
    colour-science) recomputed with the installed colour-science: equal in
    every bit, and every code of a real image reads its entry; a 16-bit image
    still goes through colour-science itself."""
    import colour

    from wavefront.data.make_srgb8_decoding import colour_srgb8_decoding
    from wavefront.textures import srgb_decoding

    table = srgb_decoding(255)
    np.testing.assert_array_equal(table.view(np.uint32), colour_srgb8_decoding().view(np.uint32))
    every = np.arange(256, dtype=np.uint8).reshape(16, 16, 1).repeat(3, axis=2)
    texture = ImageTexture(write_png(tmp_path / "codes.png", every))
    expected = colour.cctf_decoding(every / 255.0, function="sRGB").astype(np.float32)
    np.testing.assert_array_equal(texture.pixels, expected)
    wide = srgb_decoding(65535)
    np.testing.assert_array_equal(wide[::257], colour.cctf_decoding(np.arange(256) / 255.0,
                                                                    function="sRGB").astype(np.float32))


def test_an_8bit_texture_loads_without_importing_colour_science(tmp_path):
    path = write_png(tmp_path / "tiny.png", TINY)
    code = (f"import sys, wavefront; t = wavefront.ImageTexture({path!r}); "
            "assert 'colour' not in sys.modules, 'colour imported'; print(t.pixels.shape)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "(2, 3, 3)"


@pytest.mark.parametrize("u, v, row, column", [
    (0.0, 0.0, 1, 0), (0.99, 0.0, 1, 2), (0.5, 0.25, 1, 1),  # v = 0 is the bottom row, as in RTOW
    (0.0, 1.0, 0, 0), (0.5, 0.75, 0, 1), (0.34, 0.51, 0, 1), (1.0, 1.0, 0, 2),
    (-3.0, 7.0, 0, 0),  # outside [0, 1]: clamped to the edge
])
def test_nearest_lookup_at_known_uv(tmp_path, u, v, row, column):
    texture = ImageTexture(write_png(tmp_path / "tiny.png", TINY), filter="nearest")
    np.testing.assert_array_equal(texture.lookup(np.array([[u], [v]]))[:, 0], texture.pixels[row, column])


def test_bilinear_lookup_at_texel_centres_and_between(tmp_path):
    texture = ImageTexture(write_png(tmp_path / "tiny.png", TINY))
    assert texture.filter == "bilinear"
    p = texture.pixels.astype(np.float64)
    centre = lambda row, col: ((col + 0.5) / 3, 1 - (row + 0.5) / 2)  # noqa: E731
    for row in range(2):
        for col in range(3):
            u, v = centre(row, col)
            np.testing.assert_allclose(texture.lookup(np.array([[u], [v]]))[:, 0], p[row, col], atol=1e-6)
    # half way between the centres of (0, 0) and (0, 1): the mean; and the middle of four texels
    np.testing.assert_allclose(texture.lookup(np.array([[1 / 3], [0.75]]))[:, 0], (p[0, 0] + p[0, 1]) / 2, atol=1e-6)
    np.testing.assert_allclose(texture.lookup(np.array([[1 / 3], [0.5]]))[:, 0],
                               (p[0, 0] + p[0, 1] + p[1, 0] + p[1, 1]) / 4, atol=1e-6)
    # a wrong filter (nearest) differs there: the test can tell them apart
    assert not np.allclose(lookup(texture.pixels, np.array([[1 / 3], [0.5]]), "nearest")[:, 0],
                           (p[0, 0] + p[0, 1] + p[1, 0] + p[1, 1]) / 4)


@pytest.mark.parametrize("filter", ["nearest", "bilinear"])
def test_repeat_wraps_and_clamp_stops_at_the_edge(tmp_path, filter):
    """``wrap: repeat`` tiles the picture (u + 1 and v - 2 look up the same
    texel as u, v); ``clamp`` (the default, RTOW's) holds the edge; each
    axis takes its own mode."""
    p = ImageTexture(write_png(tmp_path / "tiny.png", TINY)).pixels.astype(np.float64)
    repeat = ImageTexture(pixels=p.astype(np.float32), filter=filter, wrap="repeat")
    clamp = ImageTexture(pixels=p.astype(np.float32), filter=filter)
    assert clamp.wrap == ("clamp", "clamp") and repeat.wrap == ("repeat", "repeat")
    uv = np.random.default_rng(5).random((2, 50))
    base = repeat.lookup(uv)
    np.testing.assert_allclose(repeat.lookup(uv + np.array([[1.0], [-2.0]])), base, atol=1e-12)
    np.testing.assert_allclose(repeat.lookup(uv + np.array([[-7.0], [3.0]])), base, atol=1e-12)
    # at u = 0 (the seam of a globe) a repeating bilinear filter blends the last
    # column with the first; clamped, it holds the first column
    on_seam = np.array([[0.0], [0.25]])  # the bottom row's centre line
    if filter == "bilinear":
        np.testing.assert_allclose(repeat.lookup(on_seam)[:, 0], (p[1, 0] + p[1, 2]) / 2, atol=1e-6)
        np.testing.assert_allclose(clamp.lookup(on_seam)[:, 0], p[1, 0], atol=1e-6)
    else:
        np.testing.assert_allclose(repeat.lookup(np.array([[1.0], [0.25]]))[:, 0], p[1, 0])  # one past the end: wraps
        np.testing.assert_allclose(clamp.lookup(np.array([[1.0], [0.25]]))[:, 0], p[1, 2])  # the last column
    # per axis: u repeats, v clamps (a globe)
    globe = ImageTexture(pixels=p.astype(np.float32), filter=filter, wrap=["repeat", "clamp"])
    np.testing.assert_allclose(globe.lookup(np.array([[1.25], [7.0]])), clamp.lookup(np.array([[0.25], [1.0]])),
                               atol=1e-12)


def test_float_images_are_linear(tmp_path):
    import OpenEXR

    data = np.array([[[0.5, 2.0, 0.25]]], dtype=np.float32)
    channels = {c: data[:, :, i].copy() for i, c in enumerate("RGB")}
    with OpenEXR.File({"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}, channels) as f:
        f.write(str(tmp_path / "lin.exr"))
    np.testing.assert_array_equal(ImageTexture(str(tmp_path / "lin.exr")).pixels, data)
    np.testing.assert_array_equal(ImageTexture(pixels=data).pixels, data)


def test_sphere_uv_reaches_the_image_in_a_render(tmp_path):
    """A sphere lit by a white sky (lambertian furnace): each pixel's value is the
    albedo; with an image of a red top half and a blue bottom half the top of the
    sphere comes out red and the bottom blue."""
    pixels = np.zeros((2, 1, 3), dtype=np.uint8)
    pixels[0, 0] = (255, 0, 0)
    pixels[1, 0] = (0, 0, 255)
    texture = ImageTexture(write_png(tmp_path / "halves.png", pixels), filter="nearest")
    from wavefront.background import Solid

    scene = Scene(spheres=[Sphere((0, 0, 0), 1, "m")], materials={"m": Lambertian(texture)},
                  camera=Camera(look_from=(0, 0, 5), look_at=(0, 0, 0), vfov=30), width=16, height=16,
                  background=Solid((1, 1, 1)))
    image = render(scene.with_overrides(samples_per_pixel=4, max_depth=2), workers=1)
    top, bottom = image[4, 8], image[11, 8]
    assert top[0] > 0.9 and top[2] == 0 and bottom[2] > 0.9 and bottom[0] == 0


# -- noise -----------------------------------------------------------------

def test_perlin_noise_vanishes_on_the_lattice_and_is_smooth():
    perlin = Perlin.build(0)
    lattice = np.array([[0, 1, -3, 7], [0, 2, 5, -1], [0, 3, 1, 250]], dtype=np.float64)
    np.testing.assert_allclose(perlin.noise(lattice), 0.0, atol=1e-12)  # gradient noise: zero at the corners
    p = np.random.default_rng(1).uniform(-20, 20, (3, 1000))
    step = perlin.noise(p + 1e-6) - perlin.noise(p)
    assert np.abs(step).max() < 1e-4  # continuous (Hermite smoothing)
    assert np.abs(perlin.noise(p)).max() <= 1.8


def test_noise_depends_on_the_texture_seed_only():
    points = np.random.default_rng(3).uniform(-5, 5, (3, 500))
    a, b, c = (evaluate(Noise(4.0, seed), points) for seed in (0, 0, 1))
    np.testing.assert_array_equal(a, b)
    assert not np.allclose(a, c)
    assert a.min() >= 0 and a.max() <= 1 and np.array_equal(a[0], a[1])  # grey, in [0, 1]


def test_render_seed_does_not_change_the_marble():
    scene = load_scene(SCENES / "perlin_spheres.yaml")
    points = np.random.default_rng(5).uniform(-3, 3, (3, 200))
    values = []
    for seed in (0, 12345):
        cs = scene.with_overrides(seed=seed).compile()
        values.append(cs.materials.albedo_at(np.zeros(200, np.int32), points, None))
    np.testing.assert_array_equal(values[0], values[1])


# -- materials and emitters --------------------------------------------------

def test_textured_materials_compile_with_their_mean():
    table = MaterialTable.build([Lambertian(Checker(1.0, (0.2, 0.2, 0.2), (0.6, 0.6, 0.6))), Metal((0.5, 0.5, 0.5)),
                                 Emissive(Noise(2.0))])
    np.testing.assert_allclose(table.albedo[:, 0], 0.4)
    assert table.albedo_texture.tolist() == [0, -1, -1] and table.emission_texture[2] >= 0
    np.testing.assert_allclose(table.emission[:, 2], 0.5)


def test_untextured_scene_has_no_texture_table():
    assert MaterialTable.build([Lambertian(), Metal()]).textures is None


def test_texture_field_accepts_lists_and_dicts():
    assert texture_field(None, [1, 2, 3], "albedo") == (1.0, 2.0, 3.0)
    t = texture_field(None, {"type": "checker", "scale": 2, "even": {"type": "noise"}, "odd": [0, 0, 0]}, "albedo")
    assert isinstance(t, Checker) and isinstance(t.even, Noise) and t.scale == 2.0


@pytest.mark.parametrize("spec, path, problem", [
    ({"type": "checker", "scale": 0}, "albedo.scale", "must be > 0"),
    ({"type": "checker", "scale": -1}, "albedo.scale", "must be > 0"),
    ({"type": "noise", "scale": float("nan")}, "albedo.scale", "finite"),
    ({"type": "checker", "even": [0, float("nan"), 0]}, "albedo.even[1]", "finite"),
    ({"type": "marble"}, "albedo.type", "unknown value"),
    ({"scale": 1}, "albedo.type", "required key is missing"),
    ({"type": "noise", "colour": 1}, "albedo.colour", "unknown key"),
    ({"type": "image"}, "albedo.file", "required key is missing"),
    ({"type": "image", "file": "x.png", "filter": "cubic"}, "albedo.filter", "unknown value"),
    ({"type": "image", "file": "x.png", "wrap": "mirror"}, "albedo.wrap", "unknown value"),
    ({"type": "image", "file": "x.png", "wrap": ["repeat"]}, "albedo.wrap", "a list of two"),
    ({"type": "image", "file": "x.png", "wrap": ["repeat", 3]}, "albedo.wrap[1]", ""),
    ({"type": "checker", "odd": {"type": "noise", "seed": -1}}, "albedo.odd.seed", "must be >= 0"),
])
def test_bad_textures_name_the_path(spec, path, problem):
    with pytest.raises(SceneError) as e:
        Lambertian(spec)
    assert e.value.path == path and problem in e.value.problem, str(e.value)


def test_file_and_pixels_together_are_refused(tmp_path):
    with pytest.raises(SceneError) as e:
        ImageTexture(write_png(tmp_path / "tiny.png", TINY), pixels=np.zeros((1, 1, 3), np.float32))
    assert e.value.path == "file" and "not both" in e.value.problem


def test_huge_pixels_array_is_refused():
    with pytest.raises(SceneError, match="limit"):
        ImageTexture(pixels=np.broadcast_to(np.zeros((1, 1, 3), np.float32), (4097, 4097, 3)))
    assert 4097 * 4097 > MAX_TEXTURE_PIXELS


# -- bad input through the command line ---------------------------------------

def png_header_only(width, height):
    """A PNG whose header claims ``width x height`` and that holds no pixels."""
    def chunk(kind, data):
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF)
    return b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0)) + \
        chunk(b"IEND", b"")


def run(*args):
    return subprocess.run([sys.executable, "-m", "wavefront", *map(str, args)], capture_output=True, text=True,
                          timeout=300)


SCENE = """
image: {{width: 8, height: 8}}
render: {{samples_per_pixel: 1}}
materials:
  m: {{type: lambertian, albedo: {albedo}}}
spheres:
  - {{center: [0, 0, -2], radius: 0.5, material: m}}
"""


@pytest.mark.parametrize("albedo, files, path, problem", [
    ("{type: image, file: missing.png}", {}, "materials.m.albedo.file", "no such file"),
    ("{type: image, file: notes.png}", {"notes.png": b"just some text\n"}, "materials.m.albedo.file",
     "not an image"),
    ("{type: image, file: huge.png}", {"huge.png": png_header_only(5000, 5000)}, "materials.m.albedo.file",
     "huge.png: the image is 5000x5000"),
    ("{type: image, file: bad.exr}", {"bad.exr": b"\x76\x2f\x31\x01" + b"\0" * 40}, "materials.m.albedo.file",
     "cannot read as OpenEXR"),
    ("{type: image, file: cut.png}", {"cut.png": png_header_only(4, 4)}, "materials.m.albedo.file",
     "cannot decode"),
    ("{type: image, file: .}", {}, "materials.m.albedo.file", "not a regular file"),
    ("{type: checker, scale: 0}", {}, "materials.m.albedo.scale", "must be > 0"),
    ("{type: checker, scale: -0.5, even: [1, 1, 1]}", {}, "materials.m.albedo.scale", "must be > 0"),
    ("{type: noise, scale: .nan}", {}, "materials.m.albedo.scale", "finite"),
    ("{type: checker, odd: {type: image, file: gone.png}}", {}, "materials.m.albedo.odd.file", "no such file"),
    ("{type: wood}", {}, "materials.m.albedo.type", "unknown value"),
    ("{type: noise, octaves: 3}", {}, "materials.m.albedo.octaves", "unknown key"),
    ("{type: image, file: x.png, wrap: [repeat, tile]}", {}, "materials.m.albedo.wrap[1]", "unknown value"),
])
def test_bad_texture_input_through_the_cli(tmp_path, albedo, files, path, problem):
    scene = tmp_path / "scene.yaml"
    scene.write_text(SCENE.format(albedo=albedo))
    for name, data in files.items():
        (tmp_path / name).write_bytes(data)
    out = tmp_path / "out.png"
    r = run("render", scene, "-o", out, "-q")
    assert r.returncode == 2, r.stderr
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in r.stderr, r.stderr
    assert str(scene) in lines[0] and path in lines[0] and problem in lines[0], lines[0]
    assert not out.exists()


def test_image_path_is_relative_to_the_scene_file(tmp_path):
    (tmp_path / "sub").mkdir()
    write_png(tmp_path / "sub" / "tex.png", TINY)
    scene = tmp_path / "sub" / "scene.yaml"
    scene.write_text(SCENE.format(albedo="{type: image, file: tex.png, filter: nearest}"))
    loaded = load_scene(scene)
    assert loaded.materials["m"].albedo.pixels.shape == (2, 3, 3)


def test_fingerprint_covers_image_pixels(tmp_path):
    from wavefront.film import scene_fingerprint

    def scene_with(pixels):
        return Scene(spheres=[Sphere((0, 0, -2), 0.5, "m")],
                     materials={"m": Lambertian(ImageTexture(pixels=pixels))}, width=8, height=8)

    a = np.zeros((4, 4, 3), np.float32)
    b = a.copy()
    b[3, 3, 1] = 0.5
    assert scene_fingerprint(scene_with(a)) == scene_fingerprint(scene_with(a.copy()))
    assert scene_fingerprint(scene_with(a)) != scene_fingerprint(scene_with(b))
    assert scene_fingerprint(scene_with(a)) != scene_fingerprint(
        Scene(spheres=[Sphere((0, 0, -2), 0.5, "m")], materials={"m": Lambertian(Noise(1.0, seed=3))}, width=8,
              height=8))


# -- textured emitters and Whitted ----------------------------------------------

def lamp_scene(light_sampling, spp=256):
    """A quad lamp facing down over a floor; its image is bright on the left
    (x < 0) and dark on the right, so the floor below the left half is lit more."""
    from wavefront import Quad
    from wavefront.background import Solid
    from wavefront.scene import RenderSettings

    pixels = np.zeros((1, 2, 3), np.float32)
    pixels[0, 0] = 8.0  # u < 1/2: the quad's first half along u
    lamp = Emissive(ImageTexture(pixels=pixels, filter="nearest"))
    # the lamp: u along +x, v along +z, so cross(u, v) = -y: it shines down
    quads = [Quad((-1, 1, -0.5), (2, 0, 0), (0, 0, 1), "lamp"),
             Quad((-3, 0, 3), (6, 0, 0), (0, 0, -6), "floor")]
    return Scene(quads=quads, materials={"lamp": lamp, "floor": Lambertian((0.7, 0.7, 0.7))},
                 background=Solid((0, 0, 0)),
                 camera=Camera(look_from=(0, 4, 0), look_at=(0, 0, 0), vup=(0, 0, -1), vfov=60),
                 width=24, height=24, render=RenderSettings(samples_per_pixel=spp, max_depth=2, seed=5,
                                                            light_sampling=light_sampling, russian_roulette=False))


def test_textured_light_is_sampled_with_its_texture():
    on, off = (render(lamp_scene(nee), workers=1).astype(np.float64) for nee in (True, False))
    # the camera looks straight down; image columns run along x
    left_on, right_on = on[:, :8].mean(), on[:, 16:].mean()
    left_off, right_off = off[:, :8].mean(), off[:, 16:].mean()
    assert left_off > 1.5 * right_off  # the bright half lights the floor under it
    assert abs(left_on - left_off) < 0.1 * left_off and abs(right_on - right_off) < 0.15 * right_off


def test_whitted_reads_textured_diffuse_colour():
    from wavefront import PointLight
    from wavefront.background import Solid
    from wavefront.scene import RenderSettings

    floor = Lambertian(Checker(1.0, (1.0, 0.0, 0.0), (0.0, 0.0, 1.0)))
    scene = Scene(spheres=[Sphere((0, -1000, 0), 1000, "floor")], materials={"floor": floor},
                  background=Solid((0, 0, 0)), camera=Camera(look_from=(0, 5, 0), look_at=(0, 0, 0), vup=(0, 0, -1), vfov=60),
                  lights=(PointLight((0, 10, 0), (1, 1, 1)),), width=16, height=16,
                  render=RenderSettings(samples_per_pixel=1, integrator="whitted"))
    image = render(scene, workers=1).reshape(-1, 3)
    red = (image[:, 0] > 0.1) & (image[:, 2] == 0)
    blue = (image[:, 2] > 0.1) & (image[:, 0] == 0)
    assert red.sum() > 30 and blue.sum() > 30 and (red | blue).all()


# -- hostile documents ---------------------------------------------------------

TEXTURED = {
    "image": {"width": 8, "height": 6},
    "render": {"samples_per_pixel": 1},
    "materials": {
        "floor": {"type": "lambertian", "albedo": {"type": "checker", "scale": 0.5, "even": [0.2, 0.3, 0.1],
                                                   "odd": {"type": "noise", "scale": 4, "seed": 2}}},
        "lamp": {"type": "emissive", "color": {"type": "noise", "scale": 1}},
        "tint": {"type": "metal", "albedo": {"type": "checker", "even": [1, 1, 1], "odd": [0, 0, 0]}, "fuzz": 0.1},
    },
    "spheres": [{"center": [0, 0, -1], "center1": [0, 0.3, -1], "radius": 0.5, "material": "floor"},
                {"center": [1, 0, -1], "radius": 0.3, "material": "lamp"},
                {"center": [-1, 0, -1], "radius": 0.3, "material": "tint", "center1": [-1, 0, -1.2]}],
}


def test_textured_document_is_valid():
    from wavefront.scenefile import scene_from_dict

    render(scene_from_dict(TEXTURED, source="fuzz.yaml"), workers=1)


@settings(max_examples=300, deadline=None)
@given(st.data())
def test_mutated_textured_documents_fail_at_their_path(data):
    import copy

    from wavefront.scenefile import scene_from_dict

    doc = copy.deepcopy(TEXTURED)
    candidates = [p for p, _, _ in paths(doc) if p.startswith(("materials", "spheres"))]
    target = data.draw(st.sampled_from(candidates))
    parent, key = next((parent, key) for p, parent, key in paths(doc) if p == target)
    if data.draw(st.booleans()) and isinstance(parent, dict):
        del parent[key]
    else:
        parent[key] = data.draw(BAD_VALUES)
    try:
        scene_from_dict(doc, source="fuzz.yaml")
    except SceneError as e:
        assert str(e).startswith("fuzz.yaml: "), str(e)
        related = e.path.startswith(target) or target.startswith(e.path) or \
            (target.startswith("materials") and e.path.startswith("spheres"))
        assert related, (e.path, target, str(e))


def test_light_samples_carry_the_texture_a_ray_would_see(tmp_path):
    """For textured emitters of every kind (a turned sphere, a quad, a triangle),
    the radiance a light sample reports equals what a ray from the reference point
    to the sampled point finds there: sampling and hitting agree on ``uv``."""
    from wavefront import Quad, Triangle
    from wavefront.scene import RenderSettings

    write_png(tmp_path / "map.png", np.random.default_rng(0).integers(0, 256, (16, 32, 3)))
    glow = Emissive(ImageTexture(str(tmp_path / "map.png")))
    scene = Scene(spheres=[Sphere((0, 0, 0), 1, "glow", transform=[{"rotate": {"axis": [1, 1, 0], "angle": 70}},
                                                                   {"translate": [0, 0, -4]}])],
                  quads=[Quad((1.5, -1, -5), (1, 0, 1), (0, 2, 0), "glow")],
                  triangles=[Triangle(((-3, -1, -5), (-1.5, -1, -4), (-2, 1, -4.5)), "glow")],
                  materials={"glow": glow}, width=8, height=8, render=RenderSettings(samples_per_pixel=1))
    cs = scene.compile()
    emitters = cs.emitters
    n = 3000
    rng = np.random.default_rng(1)
    reference = np.zeros((3, n))
    sample = emitters.sample(reference, rng.random(n), rng.random((2, n)))
    hits = cs.shapes.intersect(reference, sample.direction)
    ok = np.flatnonzero((sample.radiance.max(axis=0) > 0) & np.isclose(hits.t, sample.distance, rtol=1e-9))
    assert ok.size > n // 2
    surface = cs.shapes.surface(reference[:, ok], sample.direction[:, ok], hits.t[ok], hits.primitive_idx[ok], uv=True)
    seen = cs.materials.emission_at(surface.material_idx, surface.point, surface.uv)
    np.testing.assert_allclose(seen, sample.radiance[:, ok], atol=2e-4)
    kinds = set(cs.shapes.kind_of(hits.primitive_idx[ok]).tolist())
    assert kinds == {0, 1, 2}  # every kind was checked


def test_a_turned_sphere_turns_its_uv():
    """RTOW's rotate_y intersects in object space, so an image turns with the sphere:
    turned 90 degrees about y (which takes -x to +z), the point the camera sees
    (+z) has the uv that -x has on a sphere that is not turned."""
    from wavefront.shapes.sphere import sphere_uv

    turned = Sphere((0, 0, 0), 1, "m", transform=[{"rotate": {"axis": [0, 1, 0], "angle": 90}}])
    scene = Scene(spheres=[turned], materials={"m": Lambertian()}, width=4, height=4)
    cs = scene.compile()
    origin, direction = np.array([[0.0], [0.0], [5.0]]), np.array([[0.0], [0.0], [-1.0]])
    hits = cs.shapes.intersect(origin, direction)
    uv = cs.shapes.surface(origin, direction, hits.t, hits.primitive_idx, uv=True).uv
    # R = [[0, 0, 1], [0, 1, 0], [-1, 0, 0]] (right-hand rule), so R^T (0, 0, 1) = (-1, 0, 0)
    np.testing.assert_allclose(uv, sphere_uv(np.array([[-1.0], [0.0], [0.0]])), atol=1e-12)
    assert not np.allclose(uv, sphere_uv(np.array([[0.0], [0.0], [1.0]])))


def test_image_beyond_the_memory_budget_is_refused_from_its_header(tmp_path):
    write_png(tmp_path / "big.png", np.full((2048, 2048, 3), 100, np.uint8))  # 96 MiB to load, a small file
    scene = tmp_path / "scene.yaml"
    scene.write_text(SCENE.format(albedo="{type: checker, odd: {type: image, file: big.png}}"))
    out = tmp_path / "out.png"
    r = run("render", scene, "-o", out, "--memory", "128M", "-q")
    assert r.returncode == 2, r.stderr
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and "materials.m.albedo.odd.file" in lines[0] and "memory budget" in lines[0], r.stderr
    assert not out.exists()
    assert run("render", scene, "-o", out, "--memory", "1G", "-q").returncode == 0 and out.exists()
