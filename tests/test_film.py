"""The film and its checkpoints: fingerprints of the whole scene, files that
are not checkpoints, and checkpoint writes that fail late."""

import errno
import hashlib
import io
import zipfile

import numpy as np
import pytest

from wavefront import Lambertian, RenderSettings, Scene, Sphere, cli
from wavefront.film import CheckpointError, Film, _feed, load_checkpoint, save_checkpoint, scene_fingerprint

from .test_cli import SMALL, run
from .test_furnace import SCENES


def tiny_scene(**kw):
    return Scene(spheres=[Sphere((0, 0, -1), 0.5, "m")], materials={"m": Lambertian()}, width=4, height=3, **kw)


def digest(value):
    h = hashlib.sha256()
    _feed(h, value)
    return h.hexdigest()


def test_fingerprint_covers_every_element_of_large_arrays():
    a = np.zeros(100_000)
    b = a.copy()
    b[50_000] = 1e-300
    assert repr(a) == repr(b)  # what the old fingerprint hashed
    assert digest(a) != digest(b)
    assert digest(0.1) != digest(0.1 + 2**-56) and digest(1) != digest(1.0) and digest("1") != digest(1)


def test_fingerprint_changes_with_any_sphere_of_a_big_scene():
    spheres = [Sphere((i, 0, -5), 0.25, "m") for i in range(3000)]
    base = Scene(spheres=spheres, materials={"m": Lambertian()})
    moved = list(spheres)
    moved[1500] = Sphere((1500, 0, -5), 0.2500000001, "m")
    assert scene_fingerprint(base) != scene_fingerprint(base.replace(spheres=moved))
    assert scene_fingerprint(base) == scene_fingerprint(base.replace(spheres=list(spheres)))


def test_fingerprint_covers_the_sampler():
    """A checkpoint of a sobol render cannot be resumed as an independent one (its samples would mix)."""
    scene = Scene(spheres=[Sphere((0, 0, -5), 1, "m")], materials={"m": Lambertian()})
    assert scene.render.sampler == "sobol"
    assert scene_fingerprint(scene) != scene_fingerprint(scene.with_overrides(sampler="independent"))


def test_fingerprint_leaves_out_the_name_so_a_renamed_scene_file_resumes(tmp_path):
    """The name (metadata, the file's stem by default) decides nothing in the image."""
    scene = tiny_scene()
    assert scene_fingerprint(scene.replace(name="renamed")) == scene_fingerprint(scene)
    assert scene_fingerprint(scene.with_overrides(seed=3)) != scene_fingerprint(scene)
    ck, out = tmp_path / "ck.npz", tmp_path / "out.npy"
    first, second = tmp_path / "first.yaml", tmp_path / "second.yaml"
    first.write_text((SCENES / "three_spheres.yaml").read_text())
    second.write_text(first.read_text())
    args = ("--width", 8, "--height", 4, "--spp", 1, "--max-depth", 3)
    assert run("render", first, "-o", out, "--checkpoint", ck, *args).returncode == 0
    r = run("render", second, "-o", tmp_path / "again.npy", "--resume", ck, *args)
    assert r.returncode == 0, r.stderr
    np.testing.assert_array_equal(np.load(tmp_path / "again.npy"), np.load(out))


def test_a_scene_with_mesh_and_texture_files_resumes_from_another_directory(tmp_path):
    """The fingerprint hashes the meshes' and pictures' content, not the paths they were
    read from: ``wavefront render da/scene.yaml`` then ``cd da && wavefront render
    scene.yaml --resume ...`` was refused as a different scene (a reviewer's case)."""
    import shutil

    folder = tmp_path / "da"
    shutil.copytree(SCENES / "models", folder / "models")
    shutil.copy(SCENES / "mesh.yaml", folder / "scene.yaml")
    shutil.copy(SCENES / "earthmap.png", folder / "earthmap.png")
    text = (folder / "scene.yaml").read_text().replace("clay:   {type: lambertian, albedo: [0.8, 0.3, 0.2]}",
                                                       "clay:   {type: lambertian, albedo: {type: image, file: earthmap.png}}")
    assert "earthmap.png" in text
    (folder / "scene.yaml").write_text(text)
    args = ("--width", 8, "--height", 4, "--spp", 1, "--max-depth", 2)
    r = run("render", "da/scene.yaml", "-o", "first.npy", "--checkpoint", "ck.npz", *args, cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    r = run("render", "scene.yaml", "-o", "../again.npy", "--resume", "../ck.npz", *args, cwd=folder)
    assert r.returncode == 0, r.stderr
    np.testing.assert_array_equal(np.load(tmp_path / "again.npy"), np.load(tmp_path / "first.npy"))


def test_round_trip_and_refusals(tmp_path):
    from wavefront.units import UnitPlan

    scene = tiny_scene(render=RenderSettings(samples_per_pixel=100))
    film = Film(4, 3)
    film.sum[:] = np.arange(36).reshape(3, 12)
    film.count[:] = 16  # what the first 5 units (passes of 1, 1, 2, 4, 8 samples) give each pixel...
    film.count[3] = 13  # ... less 3 non-finite samples dropped
    film.dropped = 3
    assert UnitPlan(4, 3, 100).samples_before(5) == 16 * 12
    ck = tmp_path / "ck.npz"
    save_checkpoint(str(ck), scene, film, 5)
    loaded, done = load_checkpoint(str(ck), scene, units_total=10)
    assert done == 5 and (loaded.sum == film.sum).all() and (loaded.count == film.count).all() and loaded.dropped == 3
    with pytest.raises(CheckpointError, match="different scene"):
        load_checkpoint(str(ck), scene.with_overrides(seed=3), units_total=10)
    with pytest.raises(CheckpointError, match="out of range"):
        load_checkpoint(str(ck), scene, units_total=4)


def hostile_checkpoint(path, scene, **arrays):
    """A zip of .npy members like a checkpoint, with the given arrays instead."""
    members = {"fingerprint": np.array(scene_fingerprint(scene)), "units_done": np.int64(0), "dropped": np.int64(0),
               "sum": np.zeros((3, 12)), "count": np.zeros(12, dtype=np.uint32)}
    members.update(arrays)
    with zipfile.ZipFile(path, "w") as z:
        for name, value in members.items():
            buffer = io.BytesIO()
            np.save(buffer, value)
            z.writestr(name + ".npy", buffer.getvalue())


@pytest.mark.parametrize("arrays", [
    {"sum": np.zeros((3, 13))},
    {"count": np.zeros(12, dtype=np.float64)},
    {"units_done": np.zeros(3)},
    {"sum": np.array([object()], dtype=object)},
    {"fingerprint": np.zeros(3)},
])
def test_hostile_checkpoints_are_refused_from_their_headers(tmp_path, arrays):
    scene = tiny_scene()
    ck = tmp_path / "bad.npz"
    hostile_checkpoint(ck, scene, **arrays)
    with pytest.raises(CheckpointError):
        load_checkpoint(str(ck), scene, units_total=10)


def test_checkpoints_whose_counts_contradict_their_units_done_are_refused(tmp_path):
    """Counts follow from units_done and the plan: a pixel has at most the samples
    its done units give it (fewer only where non-finite samples were dropped), and a
    pixel without samples has zero sums.  A reviewer's tampered files were accepted:
    units_done 0 with counts and sums (the resume added on top of them)."""
    from wavefront.units import UnitPlan

    scene = tiny_scene(render=RenderSettings(samples_per_pixel=8))
    plan = UnitPlan(4, 3, 8)
    ck = tmp_path / "bad.npz"
    for done in range(len(plan) + 1):
        full = np.zeros((3, 4), dtype=np.uint32)
        for rows, columns, samples in plan.samples_by_region(done):
            full[rows, columns] = samples
        assert full.sum() == plan.samples_before(done)
        hostile_checkpoint(ck, scene, units_done=np.int64(done), count=full.ravel(), sum=np.ones((3, 12)) * full.ravel())
        assert load_checkpoint(str(ck), scene, units_total=len(plan))[1] == done
        if done < len(plan):
            more = full.ravel() + 1
            hostile_checkpoint(ck, scene, units_done=np.int64(done), count=more, sum=np.ones((3, 12)))
            with pytest.raises(CheckpointError, match=f"more samples than the {done} units"):
                load_checkpoint(str(ck), scene, units_total=len(plan))
    hostile_checkpoint(ck, scene, units_done=np.int64(1), count=np.zeros(12, dtype=np.uint32), sum=np.ones((3, 12)),
                       dropped=np.int64(plan.samples_before(1)))
    with pytest.raises(CheckpointError, match="without samples has a non-zero sum"):
        load_checkpoint(str(ck), scene, units_total=len(plan))
    # fewer samples than the plan gives, with full sums (an image 4x too bright), unless the
    # checkpoint's dropped samples account for the difference exactly
    done = len(plan)
    hostile_checkpoint(ck, scene, units_done=np.int64(done), count=np.ones(12, dtype=np.uint32), sum=np.ones((3, 12)))
    with pytest.raises(CheckpointError, match="do not add up"):
        load_checkpoint(str(ck), scene, units_total=len(plan))
    hostile_checkpoint(ck, scene, units_done=np.int64(done), count=np.ones(12, dtype=np.uint32), sum=np.ones((3, 12)),
                       dropped=np.int64(plan.samples_before(done) - 12))
    assert load_checkpoint(str(ck), scene, units_total=len(plan))[0].dropped == plan.samples_before(done) - 12


def test_a_resumed_film_without_samples_says_so(tmp_path):
    """A finished checkpoint emptied of its samples resumes to a black image, and the
    summary counts the pixels without samples even though the render is complete."""
    scene_file = SCENES / "three_spheres.yaml"
    ck, out = tmp_path / "ck.npz", tmp_path / "out.npy"
    args = ("--width", 8, "--height", 4, "--spp", 1, "--max-depth", 3)
    assert run("render", scene_file, "-o", out, "--checkpoint", ck, *args).returncode == 0
    with np.load(ck) as z:
        members = {name: z[name] for name in z.files}
    members["count"][:] = 0
    members["sum"][:] = 0
    members["dropped"] = np.int64(32)  # every sample dropped: the counts still add up
    np.savez(ck, **members)
    r = run("render", scene_file, "-o", out, "--resume", ck, *args)
    assert r.returncode == 0 and "32 pixels without samples" in r.stderr, r.stderr


@pytest.mark.parametrize("kind", ["npy", "png", "text", "empty"])
def test_resume_of_a_file_that_is_not_a_checkpoint_is_one_line(tmp_path, kind):
    path = tmp_path / f"not-a-checkpoint.{kind}"
    if kind == "npy":
        np.save(path, np.zeros((3, 3)))
    elif kind == "png":
        assert run("render", SCENES / "three_spheres.yaml", "-o", path, *SMALL, "-q").returncode == 0
    elif kind == "text":
        path.write_text("hello")
    else:
        path.write_bytes(b"")
    out = tmp_path / "out.png"
    r = run("render", SCENES / "three_spheres.yaml", "-o", out, "--resume", path, *SMALL)
    assert r.returncode == 2 and "Traceback" not in r.stderr, r.stderr
    assert len(r.stderr.strip().splitlines()) == 1 and "not a wavefront checkpoint" in r.stderr
    assert not out.exists()


def test_a_checkpoint_that_fails_late_keeps_the_image(tmp_path, monkeypatch, capsys):
    import importlib

    render_module = importlib.import_module("wavefront.render")  # wavefront.render is the function

    def full_disk(*args, **kwargs):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(render_module, "save_checkpoint", full_disk)
    out = tmp_path / "out.npy"
    status = cli.main(["render", str(SCENES / "three_spheres.yaml"), "-o", str(out), "--checkpoint",
                       str(tmp_path / "ck.npz"), *map(str, SMALL), "--workers", "1"])
    err = capsys.readouterr().err
    assert status == 2 and "No space left on device" in err and "Traceback" not in err
    assert np.load(out).shape == (18, 32, 3)  # the finished image was written all the same


def test_an_image_that_fails_late_is_rescued(tmp_path, monkeypatch, capsys):
    import wavefront.output

    real = wavefront.output._write_npy
    calls = []

    def fails_once(f, image):
        calls.append(1)
        if len(calls) == 1:
            raise OSError(errno.ENOSPC, "No space left on device")
        real(f, image)

    monkeypatch.setattr(wavefront.output, "_write_npy", fails_once)
    monkeypatch.setenv("TMPDIR", str(tmp_path / "rescue"))
    (tmp_path / "rescue").mkdir()
    import tempfile

    monkeypatch.setattr(tempfile, "tempdir", None)
    out = tmp_path / "out.npy"
    status = cli.main(["render", str(SCENES / "three_spheres.yaml"), "-o", str(out), *map(str, SMALL),
                       "--workers", "1"])
    err = capsys.readouterr().err
    assert status == 2 and "saved to" in err and "Traceback" not in err, err
    rescued = list((tmp_path / "rescue").glob("wavefront-rescued-*.npy"))
    assert len(rescued) == 1 and str(rescued[0]) in err
    assert np.load(rescued[0]).shape == (18, 32, 3) and not out.exists()


@pytest.mark.parametrize("order", ["C", "F"])
def test_add_puts_each_tile_on_its_pixels(order):
    """Film.add writes a unit's sums through sliced views of the tile: the same
    as adding at the tile's pixel indices, also for a film whose arrays came
    in Fortran order (a checkpoint may store them so: the reshaped views must
    still be views, or the adds would be lost)."""
    from wavefront.units import plan_units

    width, height, spp = 150, 70, 3
    rng = np.random.default_rng(1)
    sums = np.zeros((3, width * height), order=order)
    film = Film(width, height, sums, np.zeros(width * height, dtype=np.uint32))
    expected_sum, expected_count = np.zeros((3, width * height)), np.zeros(width * height, dtype=np.uint32)
    for unit in plan_units(width, height, spp):
        total, count = rng.random((3, unit.pixels)), rng.integers(0, 5, unit.pixels)
        film.add(unit, total, count)
        pixels = unit.pixel_index(width)
        expected_sum[:, pixels] += total
        expected_count[pixels] += count.astype(np.uint32)
    np.testing.assert_array_equal(film.sum, expected_sum)
    np.testing.assert_array_equal(film.count, expected_count)
