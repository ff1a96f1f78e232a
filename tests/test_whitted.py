"""The Whitted integrator against hand-computed Phong and recursion counts."""

import warnings

import numpy as np
import pytest

from wavefront import Camera, Phong, PointLight, RenderSettings, Scene, SceneError, Solid, Sphere, render
from wavefront.scenefile import SceneWarning, scene_from_dict

from .test_render import assert_same_on_two_workers

WHITTED = RenderSettings(samples_per_pixel=1, integrator="whitted", max_depth=3)
BG = (0.2, 0.3, 0.4)
BALL = Phong(ambient=(0.1, 0.2, 0.3), diffuse=(0.6, 0.5, 0.4), specular=(0.5, 0.5, 0.5),
             shininess=20, reflectivity=(0.25, 0.5, 0.75))
AMBIENT = (0.3, 0.3, 0.3)
LIGHT = PointLight((0.0, 3.0, 4.0), (0.9, 0.8, 0.7))


def centre_pixel(spheres, lights, materials=None):
    """The ray through the centre of an odd-sized image: from (0,0,3) down -z."""
    scene = Scene(spheres=spheres, materials=materials or {"ball": BALL, "blocker": Phong()},
                  camera=Camera(look_from=(0, 0, 3), look_at=(0, 0, 0), vfov=10), width=5, height=5,
                  render=WHITTED, background=Solid(BG), lights=tuple(lights), ambient=AMBIENT)
    return render(scene, workers=1)[2, 2].astype(np.float64)


def hand_phong(lit_lights):
    # hit point (0, 0, 1), normal (0, 0, 1), eye direction v = (0, 0, 1)
    p = np.array([0.0, 0, 1])
    n = v = np.array([0.0, 0, 1])
    color = np.array(BALL.ambient) * AMBIENT
    for light in lit_lights:
        l = np.array(light.position) - p
        l /= np.linalg.norm(l)
        r = 2 * np.dot(n, l) * n - l
        color += np.array(light.color) * (np.array(BALL.diffuse) * max(0, np.dot(n, l))
                                          + np.array(BALL.specular) * max(0, np.dot(r, v)) ** BALL.shininess)
    # the mirror ray leaves along +z and sees the background
    return color + np.array(BALL.reflectivity) * BG


def test_unoccluded_centre_pixel_matches_hand_computed_phong():
    got = centre_pixel([Sphere((0, 0, 0), 1, "ball")], [LIGHT])
    np.testing.assert_allclose(got, hand_phong([LIGHT]), rtol=1e-6)


def test_occluder_removes_exactly_that_lights_diffuse_and_specular():
    other = PointLight((-4.0, 1.0, 2.0), (0.3, 0.3, 0.3))
    blocker = Sphere((0.0, 1.5, 2.5), 0.3, "blocker")  # halfway to LIGHT, off the camera and mirror rays
    free = centre_pixel([Sphere((0, 0, 0), 1, "ball")], [LIGHT, other])
    blocked = centre_pixel([Sphere((0, 0, 0), 1, "ball"), blocker], [LIGHT, other])
    np.testing.assert_allclose(free, hand_phong([LIGHT, other]), rtol=1e-6)
    np.testing.assert_allclose(blocked, hand_phong([other]), rtol=1e-6)  # reflection and ambient stay


@pytest.mark.parametrize("max_depth", [0, 1, 2, 3, 4, 7])
def test_facing_mirrors_show_max_depth_reflections(max_depth):
    """Between two mirrors with k_r = 1 the centre ray bounces A, B, A, ...;
    each hit adds its ambient colour, so the pixel counts the hits."""
    red = Phong(ambient=(1, 0, 0), diffuse=(0, 0, 0), reflectivity=(1, 1, 1))
    green = Phong(ambient=(0, 1, 0), diffuse=(0, 0, 0), reflectivity=(1, 1, 1))
    scene = Scene(spheres=[Sphere((-5, 0, 0), 1, "red"), Sphere((5, 0, 0), 1, "green")],
                  materials={"red": red, "green": green},
                  camera=Camera(look_from=(0, 0, 0), look_at=(-1, 0, 0), vfov=5), width=3, height=3,
                  render=RenderSettings(samples_per_pixel=1, integrator="whitted", max_depth=max_depth),
                  background=Solid((0, 0, 0)), ambient=(1, 1, 1))
    hits = max_depth + 1
    np.testing.assert_allclose(render(scene, workers=1)[1, 1], [(hits + 1) // 2, hits // 2, 0], rtol=1e-6)


def test_whitted_default_depth_is_three():
    assert RenderSettings(integrator="whitted").depth == 3
    assert RenderSettings().depth == 50


def doc(**extra):
    base = {"render": {"integrator": "whitted"}, "materials": {"m": {"type": "phong"}},
            "spheres": [{"center": [0, 0, -2], "radius": 1, "material": "m"}]}
    base.update(extra)
    return base


@pytest.mark.parametrize("extra,where", [
    ({"lights": [{"type": "point", "color": [1, 1, 1]}]}, "lights[0].position"),
    ({"lights": [{"position": [1, 2]}]}, "lights[0].position"),
    ({"lights": [{"type": "spot", "position": [0, 0, 0]}]}, "lights[0].type"),
    ({"materials": {"m": {"type": "phong", "shininess": -1}}}, "materials.m.shininess"),
    ({"materials": {"m": {"type": "phong", "reflectivity": [0, 1.5, 0]}}}, "materials.m.reflectivity[1]"),
    ({"materials": {"m": {"type": "phong", "reflectivity": [0, -0.1, 0]}}}, "materials.m.reflectivity[1]"),
    ({"ambient": [1, 1]}, "ambient"),
])
def test_bad_whitted_input_names_the_yaml_path(extra, where):
    with pytest.raises(SceneError) as e:
        scene_from_dict(doc(**extra), source="w.yaml")
    assert str(e.value).startswith(f"w.yaml: {where}: ")


def test_path_integrator_warns_that_lights_are_ignored():
    d = doc(lights=[{"position": [0, 5, 0]}])
    d["render"] = {"integrator": "path"}
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        scene_from_dict(d)
    assert any(issubclass(w.category, SceneWarning) and "ignored" in str(w.message) for w in caught)


def test_other_materials_render_sensibly_under_whitted():
    """Glass conserves energy by its Schlick weights: in a white furnace it vanishes."""
    from wavefront import Dielectric, Emissive, Lambertian, Metal

    for material, expected in [(Dielectric(1.5), 1.0), (Metal((1, 1, 1)), 1.0), (Emissive((2, 2, 2)), 2.0),
                               (Lambertian((0.5, 0.5, 0.5)), 0.0)]:
        scene = Scene(spheres=[Sphere((0, 0, 0), 1, "m")], materials={"m": material},
                      camera=Camera(look_from=(0, 0, 3), look_at=(0, 0, 0), vfov=10), width=5, height=5,
                      render=RenderSettings(samples_per_pixel=1, integrator="whitted", max_depth=20),
                      background=Solid((1, 1, 1)))
        np.testing.assert_allclose(render(scene, workers=1)[2, 2], expected, atol=1e-5, err_msg=str(material))


def test_whitted_image_does_not_depend_on_chunk_size_or_workers():
    from pathlib import Path

    from wavefront import load_scene

    scene = load_scene(Path(__file__).resolve().parent.parent / "scenes" / "whitted.yaml").with_overrides(
        width=60, height=34, samples_per_pixel=3)
    reference = render(scene, workers=1)
    np.testing.assert_array_equal(render(scene, workers=1, chunk_size=97), reference)
    assert_same_on_two_workers(scene, reference, chunk_size=2000)



def test_glass_splitting_stays_within_the_budget_and_the_image_does_not_depend_on_it(tmp_path):
    """Glass balls in a mirror box split their rays without end (a hostile
    reviewer's scene: 249 MiB under --memory 64M at depth 200).  A chunk whose
    next generation would outgrow the wavefront is traced again in halves, and
    each sample keeps at most its MAX_SAMPLE_RAYS heaviest rays, a fixed
    number, so the image is the same under any budget, worker count and chunk
    size."""
    import subprocess
    import sys

    import yaml

    doc = {"image": {"width": 8, "height": 8},
           "render": {"samples_per_pixel": 2, "max_depth": 60, "integrator": "whitted"},
           "camera": {"look_from": [0, 0, 0.9], "look_at": [0, 0, 0], "vfov": 60},
           "lights": [{"type": "point", "position": [0.5, 0.5, 0.5]}],
           "materials": {"mirror": {"type": "metal", "albedo": [1, 1, 1]},
                         "glass": {"type": "dielectric", "refraction_index": 1.5}},
           "boxes": [{"min": [-1, -1, -1], "max": [1, 1, 1], "material": "mirror", "transform": [{"scale": -1}]}],
           "spheres": [{"center": [0.3, 0, 0], "radius": 0.25, "material": "glass"},
                       {"center": [-0.3, 0, 0], "radius": 0.25, "material": "glass"},
                       {"center": [0, 0.4, -0.3], "radius": 0.25, "material": "glass"}]}
    (tmp_path / "box.yaml").write_text(yaml.safe_dump(doc))
    r = subprocess.run([sys.executable, "-m", "wavefront", "render", tmp_path / "box.yaml", "-o", tmp_path / "small.npy",
                        "--workers", "1", "--memory", "64M"], capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    assert int(r.stderr.split("peak memory ")[1].split()[0]) <= 64, r.stderr
    scene = scene_from_dict(doc, source="box.yaml")
    big = render(scene, workers=1)
    np.testing.assert_array_equal(np.load(tmp_path / "small.npy"), big)
    np.testing.assert_array_equal(render(scene, workers=2, chunk_size=7), big)
    assert np.isfinite(big).all() and big.max() > 0
    # traced directly with a wavefront of 300 rays: chunks of 75 samples outgrow it and are
    # halved down to single samples, each within MAX_SAMPLE_RAYS; the radiance is the same
    import wavefront
    from wavefront.whitted import MAX_SAMPLE_RAYS, trace_whitted

    job = wavefront.units.Job([wavefront.units.Unit(0, 0, 0, 8, 8, 0, 2)], 8, 2)
    key = wavefront.sampling.scene_key(0)
    compiled = scene.compile()
    stats = wavefront.path.TraceStats()
    narrow = trace_whitted(compiled, job, key, MAX_SAMPLE_RAYS + 44, stats)
    np.testing.assert_array_equal(trace_whitted(compiled, job, key, 1 << 16), narrow)
    assert stats.segments > 20 * job.size  # many generations of many rays a sample
