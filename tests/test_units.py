"""Job.samples and the camera's ray generation against their plain per-slot formulas.

Both are written for speed (whole pixels at once, in-place arithmetic); these
tests pin them to the straightforward definitions, bit for bit, on hostile
image sizes, sample counts and slot ranges, so a faster rewrite cannot change
which sample a slot holds or which ray a sample fires.
"""

from __future__ import annotations

import numpy as np
from hypothesis import given
from hypothesis import strategies as st

from wavefront import Camera
from wavefront import camera as camera_module
from wavefront.units import Job, plan_units
from wavefront.vecmath import normalize
from wavefront.sampling import random_in_unit_disk


def _plain_samples(job: Job, start: int, stop: int):
    """Slot -> (pixel, sample id) by the definition: unit ``k`` holds slots
    ``offsets[k]:offsets[k+1]``, numbered ``pixel_in_tile * S + s``."""
    pixels, ids = [], []
    for slot in range(start, stop):
        k = int(np.searchsorted(job.offsets, slot, side="right")) - 1
        unit = job.units[k]
        p, s = divmod(slot - int(job.offsets[k]), unit.samples_per_pixel)
        row, col = divmod(p, unit.x1 - unit.x0)
        pixel = (unit.y0 + row) * job.width + unit.x0 + col
        pixels.append(pixel)
        ids.append(pixel * job.samples_per_pixel + unit.sample_start + s)
    return np.array(pixels, dtype=np.int64), np.array(ids, dtype=np.uint64)


@given(width=st.integers(1, 150), height=st.integers(1, 150), spp=st.integers(1, 300), data=st.data())
def test_job_samples_match_the_plain_slot_formula(width, height, spp, data):
    units = list(plan_units(width, height, spp))
    first = data.draw(st.integers(0, len(units) - 1))
    last = data.draw(st.integers(first + 1, min(len(units), first + 5)))
    job = Job(units[first:last], width, spp)
    start = data.draw(st.integers(0, job.size))
    stop = data.draw(st.integers(start, min(job.size, start + 3000)))
    pixel, sample_id = job.samples(start, stop)
    expected_pixel, expected_id = _plain_samples(job, start, stop)
    assert pixel.dtype == np.int64 and sample_id.dtype == np.uint64
    np.testing.assert_array_equal(pixel, expected_pixel)
    np.testing.assert_array_equal(sample_id, expected_id)


def test_job_samples_cover_every_sample_once():
    width, height, spp = 130, 70, 37
    units = list(plan_units(width, height, spp))
    job = Job(units, width, spp)
    cuts = [0, 1, 17, 4096, 5000, 65536, 100_001, job.size]
    parts = [job.samples(a, b)[1] for a, b in zip(cuts, cuts[1:])]
    ids = np.sort(np.concatenate(parts))
    np.testing.assert_array_equal(ids, np.arange(width * height * spp, dtype=np.uint64))


def _plain_rays(frame, pixel, u):
    """RTIOW's ray generation as first written here (int divmod, (3, N) temporaries)."""
    row, col = np.divmod(pixel, frame.width)
    x, y = col + u[0], row + u[1]
    target = frame.upper_left[:, None] + frame.pixel_delta_u[:, None] * x + frame.pixel_delta_v[:, None] * y
    if frame.has_defocus:
        disk = random_in_unit_disk(u[2], u[3])
        origin = frame.center[:, None] + frame.defocus_u[:, None] * disk[0] + frame.defocus_v[:, None] * disk[1]
    else:
        origin = np.broadcast_to(frame.center[:, None], target.shape)
    return origin, normalize(target - origin)


@given(seed=st.integers(0, 2**32 - 1), defocus=st.sampled_from([0.0, 0.5, 10.0, 120.0]),
       width=st.integers(1, 5000), height=st.integers(1, 3000))
def test_generate_rays_matches_the_plain_formula_bit_for_bit(seed, defocus, width, height):
    rng = np.random.default_rng(seed)
    camera = Camera(look_from=tuple(rng.uniform(-50, 50, 3)), look_at=tuple(rng.uniform(-50, 50, 3)),
                    vfov=float(rng.uniform(1, 170)), defocus_angle=defocus)
    frame = camera.frame(width, height)
    n = 257
    # the corners, the last pixel and random ones; u up to just below 1
    pixel = np.concatenate(([0, width - 1, width * height - 1, width * (height - 1)],
                            rng.integers(0, width * height, n - 4)))
    u = rng.random((4, n))
    u[:, :4] = np.nextafter(1.0, 0.0)
    expected_origin, expected_direction = _plain_rays(frame, pixel, u)
    for block in (camera_module.RAY_BLOCK, 64):  # one block, and several with a short last one
        saved, camera_module.RAY_BLOCK = camera_module.RAY_BLOCK, block
        try:
            origin, direction = frame.generate_rays(pixel, u)
            # float32 results: the float64 rays rounded (block by block inside)
            origin32, direction32 = frame.generate_rays(pixel, u[:2], u[2:], np.float32)
        finally:
            camera_module.RAY_BLOCK = saved
        np.testing.assert_array_equal(origin, expected_origin)
        np.testing.assert_array_equal(direction, expected_direction)
        assert origin.flags.writeable and origin.flags.c_contiguous
        assert origin32.dtype == direction32.dtype == np.float32
        np.testing.assert_array_equal(origin32, expected_origin.astype(np.float32))
        np.testing.assert_array_equal(direction32, expected_direction.astype(np.float32))


def test_pixel_rows_and_columns_are_exact_at_the_largest_image():
    from wavefront.scene import MAX_PIXELS
    width = 3
    frame = Camera().frame(width, MAX_PIXELS // width)
    pixel = np.arange(MAX_PIXELS - 3 * width, MAX_PIXELS - 1)  # row ends and starts near 2^28
    u = np.zeros((2, pixel.size))
    _, direction = frame.generate_rays(pixel, u)
    _, expected = _plain_rays(frame, pixel, u)
    np.testing.assert_array_equal(direction, expected)


def _plain_reduce(job: Job, radiance: np.ndarray):
    """Per unit: the sum of each pixel's samples that are finite in every channel, their count, the rest."""
    out = []
    for k, unit in enumerate(job.units):
        block = radiance[:, job.offsets[k]:job.offsets[k + 1]].reshape(3, unit.pixels, unit.samples_per_pixel)
        finite = np.isfinite(block).all(axis=0)
        total = np.where(finite, block, 0.0).sum(axis=2)
        count = finite.sum(axis=1)
        out.append((unit, total, count, int(finite.size - count.sum())))
    return out


@given(seed=st.integers(0, 2**32 - 1), bad=st.sampled_from(["none", "nan", "inf", "-inf", "overflow", "mixed"]))
def test_reduce_drops_exactly_the_non_finite_samples(seed, bad):
    rng = np.random.default_rng(seed)
    units = list(plan_units(70, 40, 21))[2:9]
    job = Job(units, 70, 21)
    radiance = rng.random((3, job.size)) * 10
    rows = rng.integers(0, job.size, 5)
    channels = rng.integers(0, 3, 5)
    if bad in ("nan", "inf", "-inf"):
        radiance[channels, rows] = float(bad)
    elif bad == "overflow":  # finite samples whose sum overflows: kept, the sum infinite (as before)
        radiance[:, rows] = 1e308
    elif bad == "mixed":
        radiance[channels[:2], rows[:2]] = np.nan
        radiance[:, rows[2:]] = 1e308
    for (unit, total, count, dropped), (_, e_total, e_count, e_dropped) in zip(job.reduce(radiance),
                                                                             _plain_reduce(job, radiance)):
        np.testing.assert_array_equal(total, e_total)
        if isinstance(count, int):  # one count for every pixel: only when nothing was dropped
            assert e_dropped == 0 and (e_count == count).all() and dropped == 0
        else:
            np.testing.assert_array_equal(count, e_count)
            assert count.dtype == e_count.dtype and dropped == e_dropped
