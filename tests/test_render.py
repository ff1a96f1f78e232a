"""Determinism and the render driver."""

import dataclasses
import sys

import numpy as np
import pytest

from wavefront import Camera, Lambertian, Scene, Sphere, load_scene, render, render_scene
from wavefront.memory import MemoryBudgetError, MiB
from wavefront.render import plan_memory
from wavefront.units import PASS_SAMPLES, plan_units

from .test_furnace import SCENES


@pytest.fixture(scope="module", params=["sobol", "independent"])
def scene(request):
    # 70x40 is not a multiple of the tile size and 20 spp is not a multiple
    # of the pass size, so edge tiles and short passes are exercised (and
    # sobol's permutation walks cycles: 20 is no power of two).
    return load_scene(SCENES / "three_spheres.yaml").with_overrides(width=70, height=40, samples_per_pixel=20,
                                                                     sampler=request.param)


@pytest.fixture(scope="module")
def reference_image(scene):
    return render(scene, workers=1)


def test_same_seed_same_image(scene, reference_image):
    np.testing.assert_array_equal(render(scene, workers=1), reference_image)


def test_different_seed_different_image(scene, reference_image):
    assert not np.array_equal(render(scene.with_overrides(seed=2), workers=1), reference_image)


@pytest.mark.parametrize("chunk_size", [257, 1000, 4096, 65536])
def test_chunk_size_does_not_change_the_image(scene, reference_image, chunk_size):
    np.testing.assert_array_equal(render(scene, workers=1, chunk_size=chunk_size), reference_image)


def assert_same_on_two_workers(scene, image, chunk_size: int) -> None:
    """``scene`` rendered by two worker processes is ``image``, bit for bit
    (and two workers really ran: a budget could fall back to one quietly)."""
    result = render_scene(scene, workers=2, chunk_size=chunk_size, memory=4 << 30)
    assert result.stats.workers == 2  # the budget did not quietly fall back to one process
    np.testing.assert_array_equal(result.image, image)


def test_worker_count_does_not_change_the_image(scene, reference_image):
    assert_same_on_two_workers(scene, reference_image, chunk_size=1000)


def test_image_layout_and_finiteness(reference_image):
    assert reference_image.shape == (40, 70, 3) and reference_image.dtype == np.float32
    assert np.isfinite(reference_image).all() and reference_image.min() >= 0


def test_row_zero_is_the_top_of_the_image():
    """Looking at the horizon over a black ground: sky above, black below."""
    scene = Scene(spheres=[Sphere((0, -1000, 0), 999, "black")], materials={"black": Lambertian((0, 0, 0))},
                  camera=Camera(look_from=(0, 0, 0), look_at=(0, 0, -1)), width=20, height=20)
    image = render(scene.with_overrides(samples_per_pixel=2), workers=1)
    assert image[0].min() > 0.5 and image[-1].max() == 0.0


def test_stats_count_samples_and_segments(scene):
    result = render_scene(scene, workers=1)
    s = result.stats
    assert s.samples == 70 * 40 * 20
    assert s.segments >= s.samples and not s.partial and s.dropped == 0


@pytest.mark.parametrize("width, height, spp", [(130, 70, 2 * PASS_SAMPLES + 3), (1, 1, 100_000), (65, 3, 17),
                                                 (3, 200, 1), (400, 225, 10)])
def test_units_cover_every_pixel_sample_once(width, height, spp):
    plan = plan_units(width, height, spp)
    counts = np.zeros(width * height, dtype=int)
    done = 0
    for i, u in enumerate(plan):
        assert plan.samples_before(i) == done and u.index == i and u.samples_per_pixel > 0
        np.add.at(counts, u.pixel_index(width), u.samples_per_pixel)
        done += u.size
    assert (counts == spp).all() and done == plan.total_samples == plan.samples_before(len(plan))


def test_the_first_pass_gives_every_pixel_a_sample():
    plan = plan_units(400, 225, 16)  # one pass of 16 used to fill the image tile by tile
    first = [u for u in plan if u.sample_start == 0]
    assert [u.index for u in first] == list(range(len(first)))  # the first units of the render
    assert all(u.samples_per_pixel == 1 for u in first)
    assert sum(u.pixels for u in first) == 400 * 225


def test_the_plan_does_not_grow_with_the_sample_count():
    import tracemalloc

    tracemalloc.start()
    plan = plan_units(3840, 2160, 1 << 24)
    last = plan[len(plan) - 1]
    size, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    assert len(plan) > 10**9 and last.sample_stop == 1 << 24
    assert peak < 1 << 20


def test_tasks_cover_the_units_in_order_and_shrink_towards_the_end():
    from wavefront.render import TASK_WAVEFRONTS, plan_tasks

    plan = plan_units(400, 225, 10)
    capacity = 65536
    tasks = list(plan_tasks(plan, capacity, workers=2))
    assert [u for task in tasks for u in task] == list(plan)
    sizes = [sum(u.size for u in task) for task in tasks]
    assert max(sizes) < TASK_WAVEFRONTS * capacity + max(u.size for u in plan)  # a target plus one unit
    assert sizes == sorted(sizes, reverse=True) and sizes[-1] < sizes[0] / 2  # long first, short last
    resumed = list(plan_tasks(plan, capacity, workers=2, first_unit=len(plan) - 3))
    assert [u for task in resumed for u in task] == list(plan)[-3:]
    assert list(plan_tasks(plan, capacity, workers=2, first_unit=len(plan))) == []


def test_a_small_render_is_shared_out_among_the_workers():
    from wavefront.render import SMALLEST_SHARED_TASK, plan_tasks

    capacity = 65536
    for width, height, spp, workers in ((128, 128, 4, 2), (128, 128, 16, 2), (200, 100, 3, 3), (128, 128, 8, 4)):
        plan = plan_units(width, height, spp)
        tasks = list(plan_tasks(plan, capacity, workers=workers))
        assert [u for task in tasks for u in task] == list(plan)
        assert len(tasks) >= workers, (width, height, spp, workers)
    # a share that fits in one task is one task (one tail a worker); a larger one is guided
    from wavefront.render import TASK_WAVEFRONTS
    for width, height, spp, workers in ((128, 128, 16, 2), (256, 256, 8, 2), (200, 100, 30, 3)):
        plan = plan_units(width, height, spp)
        assert plan.total_samples <= workers * TASK_WAVEFRONTS * capacity
        assert len(list(plan_tasks(plan, capacity, workers=workers))) == workers, (width, height, spp, workers)
    assert len(list(plan_tasks(plan_units(128, 128, 64), capacity, workers=2))) > 2
    # units grow (sample passes double), and resuming starts mid-plan: still one near-equal task a
    # worker (closing a task only past its share made the first swallow nearly everything)
    for width, height, spp, cap, workers, first in ((64, 64, 32, 16384, 2, 1), (48, 48, 64, 65536, 2, 1),
                                                    (32, 32, 100, 16384, 3, 0), (48, 48, 100, 65536, 3, 0),
                                                    (64, 64, 64, 32768, 4, 1), (160, 120, 32, 65536, 8, 0)):
        plan = plan_units(width, height, spp)
        sizes = [sum(u.size for u in task) for task in plan_tasks(plan, cap, workers=workers, first_unit=first)]
        assert len(sizes) == workers and max(sizes) <= 1.25 * sum(sizes) / workers, (width, height, spp, sizes)
    # below a pool's start-up cost a render stays one task (inline)
    tiny = plan_units(128, 128, 1)
    assert tiny.total_samples <= SMALLEST_SHARED_TASK
    assert len(list(plan_tasks(tiny, capacity, workers=2))) == 1


def test_tasks_are_planned_lazily():
    from wavefront.render import plan_tasks

    tasks = plan_tasks(plan_units(3840, 2160, 1 << 24), 65536, workers=2)
    assert sum(u.size for u in next(tasks)) >= 65536


def test_memory_plan_fits_the_budget_or_refuses_with_the_estimate():
    from wavefront.render import GOOD_CAPACITY, MemoryBudgetError, plan_memory

    MiB = 1 << 20
    common = dict(base=60 * MiB, film=10 * MiB, per_worker=60 * MiB, output=20 * MiB)
    big = plan_memory(1 << 30, 2, None, **common)
    assert big.workers == 2 and big.peak <= 1 << 30
    small = plan_memory(200 * MiB, 2, None, **common)  # two workers would each cost 60 MiB more
    assert small.peak <= 200 * MiB and (small.workers == 1 or small.capacity >= GOOD_CAPACITY)
    assert plan_memory(1 << 30, 2, 1000, **common).capacity == 1000  # an explicit chunk size is kept
    with pytest.raises(MemoryBudgetError, match=r"needs about \d+ MiB"):
        plan_memory(64 * MiB, 2, None, **common)


def test_auto_precision_follows_the_scene_extent():
    from wavefront.scene import precision_of

    assert precision_of(load_scene(SCENES / "three_spheres.yaml")) == np.float32  # ground radius 100
    # ground radius 1000: anchored float32 (tests/test_precision.py); moving balls keep float64
    assert precision_of(load_scene(SCENES / "final_scene.yaml")) == np.float32
    assert precision_of(load_scene(SCENES / "bouncing_spheres.yaml")) == np.float64
    forced = load_scene(SCENES / "final_scene.yaml")
    forced = forced.replace(render=dataclasses.replace(forced.render, precision="float32"))
    assert precision_of(forced) == np.float32


def test_auto_precision_keeps_small_spheres_far_out_in_float64():
    from wavefront.geometry import precision_for

    assert precision_for([0.5, 100.0], 201.5) == np.float32  # three_spheres
    assert precision_for([0.01], 100.0) == np.float64  # would move its silhouette by ~1e-3 of its radius
    assert precision_for([0.2], 1200.0) == np.float64  # too far: positions round by ~1e-4


def test_a_small_sphere_far_from_the_origin_is_intact_in_float32():
    """The textbook discriminant lost (|oc| / r)^2 of its digits: in float32 this
    ball, a hundred units out and seen from 0.06 away, did not appear at all."""
    from wavefront import Solid

    base = Scene(spheres=[Sphere((100.0, 0.0, 0.0), 0.01, "black")],
                 materials={"black": Lambertian((0.0, 0.0, 0.0))},
                 camera=Camera(look_from=(100.0, 0.0, 0.06), look_at=(100.0, 0.0, 0.0), vfov=30.0),
                 width=48, height=48, background=Solid((1.0, 1.0, 1.0)))
    images = []
    for precision in ("float32", "float64"):
        scene = base.replace(render=dataclasses.replace(base.render, samples_per_pixel=4, max_depth=1,
                                                        precision=precision))
        images.append(render(scene, workers=1))
    covered = [(image[..., 0] < 0.5).sum() for image in images]
    assert covered[1] > 500  # the ball fills much of the view
    assert abs(covered[0] - covered[1]) <= 2
    assert np.abs(images[0] - images[1]).mean() < 1e-3


def test_float32_and_float64_renders_agree(scene):
    """float32 uses the top 24 bits of the same random numbers, so the two
    precisions trace the same paths and differ only by rounding (and, at
    most, by a very rare path that a rounding difference sends elsewhere)."""
    f32 = render(scene.replace(render=dataclasses.replace(scene.render, precision="float32")), workers=1)
    f64 = render(scene.replace(render=dataclasses.replace(scene.render, precision="float64")), workers=1)
    assert abs(f32.mean() - f64.mean()) < 1e-3 * f64.mean()
    assert np.mean(np.abs(f32 - f64) > 1e-3) < 0.01


@pytest.mark.parametrize("name, overrides", [
    ("cornell_spheres.yaml", {}),  # an open room: ~1 % escape a bounce, lamp and glass
    ("checkered_spheres.yaml", {}),  # a textured albedo under a sky, one kernel
    ("simple_light.yaml", {}),  # a textured albedo and emitters: routed by kind
    ("earth.yaml", {}),  # an image texture: the stand-ins' uv
    ("three_spheres.yaml", {"sampler": "independent"}),  # three kernels, no emitter
    ("cornell_spheres.yaml", {"lamp_first": True}),  # a stand-in's primitive 0 is the lamp: never emits
    ("cornell_box.yaml", {"lamp_first": True}),  # the light quad first
])
def test_escaped_paths_left_in_the_batch_change_no_pixel(monkeypatch, name, overrides):
    """Escaped paths carried through a bounce as absorbed stand-ins
    (path.escaped) give the image of compacting them away at once, bit for
    bit: forced for every escape (fraction 1, even under a sky) and never.
    With the emitter listed first the stand-ins (primitive 0) lie on it."""
    from wavefront import path as path_module
    overrides = dict(overrides)
    lamp_first = overrides.pop("lamp_first", False)
    scene = load_scene(SCENES / name).with_overrides(width=40, height=30, samples_per_pixel=3, **overrides)
    if lamp_first:
        lamp = lambda shape: scene.materials[shape.material].__class__.__name__ == "Emissive"  # noqa: E731
        kind = "spheres" if scene.spheres and any(map(lamp, scene.spheres)) else "quads"
        shapes = getattr(scene, kind)
        scene = scene.replace(**{kind: [s for s in shapes if lamp(s)] + [s for s in shapes if not lamp(s)]})
        assert lamp(getattr(scene, kind)[0])
    images = []
    for fraction, share in ((0.0, 0.3), (1.0, 2.0)):  # a share above 1: never grouped for a mix of kernels
        monkeypatch.setattr(path_module, "ESCAPED_KEPT_FRACTION", fraction)
        monkeypatch.setattr(path_module, "GROUPED_OTHER_SHARE", share)
        images.append(render(scene, workers=1))
    np.testing.assert_array_equal(images[0], images[1])


@pytest.mark.parametrize("name, overrides", [
    ("cornell_spheres.yaml", {}),  # one lamp, three kernels, roulette
    ("simple_light.yaml", {}),  # two emitters: light choice and roulette share a pair
    ("three_spheres.yaml", {"sampler": "independent"}),  # no emitter, the independent sampler
])
def test_uniforms_drawn_together_change_no_pixel(monkeypatch, name, overrides):
    """A small bounce's uniforms drawn in one call (path.draw_together) give
    the image of each stage drawing its own, bit for bit: forced for every
    bounce and never."""
    from wavefront import path as path_module
    scene = load_scene(SCENES / name).with_overrides(width=40, height=30, samples_per_pixel=3, **overrides)
    images = []
    for paths in (0, 1 << 30):
        monkeypatch.setattr(path_module, "TOGETHER_PATHS", paths)
        images.append(render(scene, workers=1))
    np.testing.assert_array_equal(images[0], images[1])


@pytest.mark.parametrize("name, overrides", [
    ("cornell_spheres.yaml", {}),  # ~1.3 % of the paths end a bounce before roulette
    ("cornell_smoke.yaml", {}),  # media: paths scattered in fog join the batch
    ("bouncing_spheres.yaml", {}),  # motion blur: each path's time moves with it
    ("three_spheres.yaml", {"sampler": "independent"}),
])
def test_survivors_moved_into_ended_rows_change_no_pixel(monkeypatch, name, overrides):
    """Survivors moved into the rows of ended paths (path.advance, reordering
    the batch) give the image of compacting every field, bit for bit:
    forced for every bounce and never."""
    from wavefront import path as path_module
    scene = load_scene(SCENES / name).with_overrides(width=40, height=30, samples_per_pixel=3, **overrides)
    images = []
    for fraction in (0.0, 1.0):
        monkeypatch.setattr(path_module, "FILLED_FRACTION", fraction)
        images.append(render(scene, workers=1))
    np.testing.assert_array_equal(images[0], images[1])


def test_fill_moves_the_last_paths_into_the_holes():
    """PathBatch.fill: every field of the paths kept, in the order fill
    promises (each hole takes its mover); (3, N) fields views of their
    first columns (no copy), which gather reads row by row alike."""
    from wavefront.vecmath import gather
    from wavefront.batch import PathBatch
    n = 10
    batch = PathBatch(origin=np.arange(3.0 * n).reshape(3, n), direction=np.arange(3.0 * n).reshape(3, n) + 100,
                      throughput=np.arange(3.0 * n).reshape(3, n) + 200, slot=np.arange(n), state=np.arange(n, dtype=np.uint64),
                      depth=np.arange(n, dtype=np.int32), bsdf_pdf=np.arange(n) * 0.5, specular=np.arange(n) % 2 == 0,
                      eta_scale=np.arange(n) + 0.25)
    alive = np.ones(n, dtype=bool)
    alive[[1, 4, 8]] = False  # as path.advance picks them: holes 1 and 4 take movers 7 and 9 (8 ended)
    size = n - 3
    holes, movers = np.flatnonzero(~alive[:size]), np.flatnonzero(alive[size:]) + size
    np.testing.assert_array_equal(movers, [7, 9])
    want = batch.take(np.array([0, 7, 2, 3, 9, 5, 6]))
    got = batch.fill(holes, movers, size)
    assert len(got) == 7
    for name in ("origin", "direction", "throughput", "slot", "state", "depth", "bsdf_pdf", "specular", "eta_scale"):
        np.testing.assert_array_equal(getattr(got, name), getattr(want, name))
    assert not got.origin.flags.c_contiguous and got.origin.base is not None
    idx = np.array([6, 0, 4, 4])
    for name in ("origin", "direction", "throughput"):
        np.testing.assert_array_equal(gather(getattr(got, name), idx), getattr(want, name).take(idx, axis=1))
    assert got.time is None and got.media_mask is None


@pytest.mark.parametrize("unused", ["dielectric", "metal", "lambertian"])
def test_a_material_no_shape_uses_changes_nothing(unused):
    """A scene may define materials it does not use (a scene file's library of
    them): the render is the image without them, bit for bit.  An unused
    dielectric was the last scatter kernel, and the run of glass rows the
    bounce loop looked up did not exist (IndexError; session 11's review)."""
    from wavefront import Dielectric, Metal

    spare = {"dielectric": Dielectric(1.5), "metal": Metal((0.9, 0.9, 0.9), fuzz=0.1),
             "lambertian": Lambertian((0.2, 0.4, 0.6))}[unused]
    base = Scene(spheres=[Sphere((0, 0, -1), 0.5, "m"), Sphere((-1, 0, -1), 0.5, "floor"),
                          Sphere((0, -100.5, -1), 100, "floor")],
                 materials={"m": Metal((0.9, 0.9, 0.9), fuzz=0.0), "floor": Lambertian((0.5, 0.5, 0.5))},
                 camera=Camera(look_from=(0, 0.3, 1), look_at=(0, 0, -1), vfov=60)).with_overrides(
                     width=24, samples_per_pixel=4)
    with_spare = base.replace(materials={**base.materials, "spare": spare})
    expected = render_scene(base, workers=1).image
    np.testing.assert_array_equal(render_scene(with_spare, workers=1).image, expected)


def _refused_sizes(message: str, total_word: str) -> tuple[float, float]:
    """The total and the budget a refusal states, in bytes."""
    import re

    def size(text):
        number, unit = re.fullmatch(r"([\d,.]+) (MiB|bytes)", text).groups()
        return float(number.replace(",", "")) * (MiB if unit == "MiB" else 1)

    total = re.search(rf"([\d,.]+ (?:MiB|bytes)){total_word}", message)[1]
    budget = re.search(r"memory budget of ([\d,.]+ (?:MiB|bytes))", message)[1]
    return size(total), size(budget)


@pytest.mark.parametrize("held,need,memory", [
    (125.3, 10.1, 135.3),  # 135.4 in all over 135.3: both "135 MiB"
    (100.0, 35.0, 135.0 - 1 / MiB),  # one byte over: "135 MiB ... of 135 MiB"
    (4.0, 1.04, 5.01),
])
def test_a_memory_refusal_never_states_a_total_not_above_its_budget(monkeypatch, held, need, memory):
    """Rounded alike to whole MiB, a refusal read "135 MiB in all, more than
    the memory budget of 135 MiB"; the total and the budget now take the
    decimals (or bytes) that show the one above the other."""
    from wavefront import memory as memory_module

    monkeypatch.setattr(memory_module, "current_rss", lambda: int(held * MiB))
    with pytest.raises(MemoryBudgetError) as e:
        memory_module.refuse_unless_fits(int(memory * MiB), int(need * MiB), "loading x")
    total, budget = _refused_sizes(str(e.value), " in all")
    assert total > budget, str(e.value)


def test_a_render_refused_just_over_its_budget_says_so():
    """plan_memory's refusal rounded its peak and the budget alike (whole MiB above 10 MiB)."""
    common = dict(base=40 * MiB + 12345, film=100 * MiB, per_worker=80 * MiB, output=1 * MiB)
    low, high = 64 * MiB, 1 << 31  # the least budget that fits
    while low < high:
        middle = (low + high) // 2
        try:
            plan_memory(middle, 1, None, **common)
            high = middle
        except MemoryBudgetError:
            low = middle + 1
    with pytest.raises(MemoryBudgetError) as e:
        plan_memory(low - 1, 1, None, **common)
    total, budget = _refused_sizes(str(e.value), r" \(")
    assert total > budget, str(e.value)


def test_a_local_cluster_refused_just_over_its_budget_says_so(monkeypatch):
    from wavefront import distributed

    monkeypatch.setattr(distributed, "current_rss", lambda: 40 * MiB + MiB // 3)
    monkeypatch.setitem(sys.modules, "dask.distributed", sys.modules.get("dask.distributed") or object())
    need = distributed.LOCAL_WORKER_BYTES + distributed.LOCAL_CLUSTER_BYTES
    with pytest.raises(distributed.SchedulerError) as e:
        distributed.local_worker_count("local:1", 40 * MiB + need + MiB // 10)
    total, budget = _refused_sizes(str(e.value), " in all")
    assert total > budget, str(e.value)
