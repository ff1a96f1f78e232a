"""Interrupted, killed and resumed renders; limits; numerical edge cases."""

import importlib
import os
import signal
import subprocess
import sys
import time

import numpy as np
import pytest

from wavefront import (Camera, Dielectric, Emissive, Lambertian, Metal, Scene, Solid, Sphere, load_scene, render,
                       render_scene)
from wavefront.output import read_png_metadata

from .test_cli import run
from .test_furnace import SCENES

SLOW = SCENES / "slow_room.yaml"


def start(*args):
    return subprocess.Popen([sys.executable, "-m", "wavefront", "render", *map(str, args)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def wait_for(path, timeout=60):
    deadline = time.monotonic() + timeout
    while not path.exists():
        assert time.monotonic() < deadline, f"{path} never appeared"
        time.sleep(0.05)


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_signal_stops_quickly_and_writes_the_partial_image(tmp_path, sig):
    out, ck = tmp_path / "partial.png", tmp_path / "ck.npz"
    # the first periodic checkpoint proves units are being merged
    proc = start(SLOW, "-o", out, "--checkpoint", ck, "--checkpoint-interval", "0.01", "--workers", 2)
    wait_for(ck)
    sent = time.monotonic()
    proc.send_signal(sig)
    _, err = proc.communicate(timeout=30)
    assert time.monotonic() - sent < 3.0, "took too long to stop"
    assert proc.returncode == 128 + sig, err
    assert "Traceback" not in err and "PARTIAL" in err
    meta = read_png_metadata(out)
    assert meta["wavefront.partial"] == "yes"
    done, total = map(int, meta["wavefront.units"].split("/"))
    assert 0 < done < total


def children_of(pid):
    found = []
    for entry in os.listdir("/proc"):
        if entry.isdigit():
            try:
                with open(f"/proc/{entry}/stat") as f:
                    if int(f.read().rsplit(")", 1)[1].split()[1]) == pid:
                        found.append(int(entry))
            except (OSError, ValueError):
                pass
    return found


def alive(pid):
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().rsplit(")", 1)[1].split()[0] != "Z"
    except OSError:
        return False


@pytest.mark.skipif(not os.path.isdir("/proc"), reason="reads /proc")
def test_workers_die_with_a_killed_parent(tmp_path):
    ck = tmp_path / "ck.npz"
    proc = start(SLOW, "-o", tmp_path / "out.png", "--checkpoint", ck, "--checkpoint-interval", "0.01",
                 "--workers", 2)
    wait_for(ck)
    workers = children_of(proc.pid)
    assert workers, "no worker processes"
    proc.kill()  # SIGKILL: the parent cannot tell anyone
    _, err = proc.communicate(timeout=30)
    deadline = time.monotonic() + 5
    while any(alive(w) for w in workers) and time.monotonic() < deadline:
        time.sleep(0.05)
    assert not any(alive(w) for w in workers), "orphaned workers still computing"
    assert "Traceback" not in err and "BrokenPipe" not in err


def test_sigterm_while_loading_gives_up_within_a_second(tmp_path):
    """A scene that is still arriving (a FIFO whose writer has not finished)."""
    fifo = tmp_path / "scene.yaml"
    os.mkfifo(fifo)
    out = tmp_path / "out.png"
    proc = subprocess.Popen([sys.executable, "-m", "wavefront", "render", str(fifo), "-o", str(out)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    with open(fifo, "w") as writer:
        writer.write("spheres:\n")
        writer.flush()
        time.sleep(0.5)  # the command is now reading
        sent = time.monotonic()
        proc.send_signal(signal.SIGTERM)
        _, err = proc.communicate(timeout=30)
    # within a second on an idle machine; an unresponsive loader would wait for
    # the writer (forever), so a margin for a loaded CI machine loses nothing
    assert time.monotonic() - sent < 5.0
    assert proc.returncode == 128 + signal.SIGTERM and "interrupted" in err and "Traceback" not in err
    assert not out.exists()


def test_a_render_stopped_after_the_first_pass_has_no_missing_pixels():
    scene = Scene(spheres=[Sphere((0, 0, -1), 0.5, "m")], materials={"m": Lambertian()}, width=200,
                  height=130).with_overrides(samples_per_pixel=16)  # 16 spp: one pass of 16 used to be all
    first_pass = {"done": 0}

    def progress(done, total):
        first_pass["done"] = done

    result = render_scene(scene, workers=1, chunk_size=4096, progress=progress,
                          should_stop=lambda: first_pass["done"] >= 200 * 130)
    s = result.stats
    assert s.partial and 0 < s.units_done < s.units_total
    assert s.pixels_without_samples == 0 and (result.film.count >= 1).all()
    assert result.image.min() > 0  # no black tiles


def test_killed_checkpointed_render_resumes_to_the_identical_image(tmp_path):
    full = tmp_path / "full.npy"
    r = run("render", SLOW, "-o", full, "--spp", 64, "-q")
    assert r.returncode == 0, r.stderr

    ck, out = tmp_path / "ck.npz", tmp_path / "resumed.npy"
    # small tasks (a small wavefront) so the first checkpoint comes early: a task is
    # merged only once its last path has ended, when the wavefront has run on well
    # into the tasks after it (the room's paths often last 50 bounces)
    proc = start(SLOW, "-o", out, "--spp", 64, "--checkpoint", ck, "--checkpoint-interval", "0.01",
                 "--workers", 1, "--chunk-size", 4096)
    wait_for(ck)
    time.sleep(0.3)
    proc.kill()  # SIGKILL: nothing gets to clean up
    proc.communicate()
    assert not out.exists()
    r = run("render", SLOW, "-o", out, "--spp", 64, "--resume", ck, "--workers", 2, "-q")
    assert r.returncode == 0, r.stderr
    np.testing.assert_array_equal(np.load(out), np.load(full))


def test_resume_with_other_settings_is_refused(tmp_path):
    ck = tmp_path / "ck.npz"
    assert run("render", SLOW, "-o", tmp_path / "a.npy", "--spp", 2, "--checkpoint", ck, "-q").returncode == 0
    r = run("render", SLOW, "-o", tmp_path / "b.npy", "--spp", 3, "--resume", ck)
    assert r.returncode == 2 and "different" in r.stderr and "Traceback" not in r.stderr
    assert not (tmp_path / "b.npy").exists()
    (tmp_path / "junk.npz").write_bytes(b"not a checkpoint")
    r = run("render", SLOW, "-o", tmp_path / "c.npy", "--resume", tmp_path / "junk.npz")
    assert r.returncode == 2 and "not a wavefront checkpoint" in r.stderr


def test_oversized_output_is_refused_up_front(tmp_path):
    t = time.monotonic()
    r = run("render", SCENES / "three_spheres.yaml", "-o", tmp_path / "huge.png", "--width", 16000, "--height", 16000)
    assert r.returncode == 2 and "MiB" in r.stderr and "--memory" in r.stderr, r.stderr
    r = run("render", SCENES / "three_spheres.yaml", "-o", tmp_path / "huge.png", "--width", 200000, "--height", 200000)
    assert r.returncode == 2 and "--width 200000 --height 200000" in r.stderr and "pixels" in r.stderr, r.stderr
    assert "Traceback" not in r.stderr
    assert time.monotonic() - t < 30 and not (tmp_path / "huge.png").exists()


def test_memory_does_not_grow_with_samples_per_pixel():
    scene = Scene(spheres=[Sphere((0, 0, -1), 0.5, "m")], materials={"m": Lambertian()}, width=64, height=36)
    few = render_scene(scene.with_overrides(samples_per_pixel=2), workers=1, chunk_size=4096).stats
    many = render_scene(scene.with_overrides(samples_per_pixel=200), workers=1, chunk_size=4096).stats
    assert many.peak_memory < few.peak_memory + 32 * 2**20  # per-sample buffers are bounded by the task size


# --- numerical edge cases ------------------------------------------------------

def white_sky_scene(spheres, materials, camera, **kw):
    return Scene(spheres=spheres, materials=materials, camera=camera, background=Solid((1, 1, 1)),
                 width=kw.pop("width", 40), height=kw.pop("height", 30), **kw).with_overrides(
        samples_per_pixel=kw.pop("spp", 4))


@pytest.mark.parametrize("radius", [1e2, 1e3, 1e6])
def test_huge_ground_has_no_acne(radius):
    """Scattered rays can never re-hit a convex sphere, so under a white sky a
    ground of albedo 0.5 shows exactly 0.5: any self-intersection (acne) would
    darken a pixel towards 0.25."""
    scene = white_sky_scene([Sphere((0, -radius, 0), radius, "g")], {"g": Lambertian((0.5, 0.5, 0.5))},
                            Camera(look_from=(0, 1.5, 4), look_at=(0, 0, 0), vfov=60))
    image = render(scene, workers=1)
    ground = image[-10:]
    np.testing.assert_array_equal(ground, np.float32(0.5))


@pytest.mark.parametrize("radius", [1e-4, 1e-2])
def test_tiny_sphere_next_to_a_huge_one_is_neither_lost_nor_acned(radius):
    camera = Camera(look_from=(0, radius, 8 * radius), look_at=(0, radius, 0), vfov=30)
    scene = white_sky_scene([Sphere((0, -1e6, 0), 1e6, "g"), Sphere((0, radius, 0), radius, "b")],
                            {"g": Lambertian((0.5, 0.5, 0.5)), "b": Metal((0.5, 0.5, 0.5))}, camera)
    image = render(scene, workers=1)
    assert np.isfinite(image).all()
    centre = image[15, 20]
    assert centre.max() < 0.9, "the tiny sphere is missing"  # a hole would show the white sky


def test_camera_at_the_centre_of_a_glass_sphere_sees_white():
    """From the centre every ray meets the glass at normal incidence: no total
    internal reflection, so every path leaves and the furnace stays white."""
    scene = white_sky_scene([Sphere((0, 0, 0), 2, "glass")], {"glass": Dielectric(1.5)},
                            Camera(look_from=(0, 0, 0), look_at=(0, 0, -1), vfov=90))
    np.testing.assert_allclose(render(scene, workers=1), 1.0, atol=1e-6)


def test_camera_inside_a_closed_lambertian_sphere_is_finite():
    scene = Scene(spheres=[Sphere((0, 0, 0), 3, "wall"), Sphere((0, 2, 0), 0.5, "lamp")],
                  materials={"wall": Lambertian((0.7, 0.7, 0.7)), "lamp": Emissive((4, 4, 4))},
                  camera=Camera(look_from=(0, 0, 0), look_at=(0, 0, -1)), width=24, height=24,
                  background=Solid((0, 0, 0))).with_overrides(samples_per_pixel=8)
    image = render(scene, workers=1)
    assert np.isfinite(image).all() and image.mean() > 0.1


def test_grazing_rays_stay_finite():
    """A sphere seen exactly edge-on at every pixel row: discriminants near 0."""
    scene = white_sky_scene([Sphere((0, 0, 0), 1, "m")], {"m": Metal((0.9, 0.9, 0.9), 0.0)},
                            Camera(look_from=(0, 1, 5), look_at=(0, 1, 0), vfov=1), width=64, height=64)
    image = render(scene, workers=1)
    assert np.isfinite(image).all()


def test_albedo_above_one_and_blazing_lamps_stay_finite():
    scene = Scene(spheres=[Sphere((0, 0, 0), 3, "wall"), Sphere((0, 2, 0), 0.5, "lamp")],
                  materials={"wall": Lambertian((50.0, 50.0, 50.0)), "lamp": Emissive((5000, 5000, 5000))},
                  camera=Camera(look_from=(0, 0, 0), look_at=(0, 0, -1)), width=16, height=16,
                  background=Solid((0, 0, 0))).with_overrides(samples_per_pixel=4, max_depth=400)
    result = render_scene(scene, workers=1)
    assert np.isfinite(result.image).all()
    # 50^400 overflows float64: those samples are dropped and counted, not written
    assert result.stats.dropped > 0


def test_a_killed_worker_costs_only_its_task(tmp_path):
    """A pool worker killed mid-render (say by the out-of-memory killer): its
    task is run again and the image is exactly the undisturbed one."""
    reference = tmp_path / "ref.npy"
    assert run("render", SLOW, "-o", reference, "--spp", 64, "--workers", 1, "-q").returncode == 0
    out, ck = tmp_path / "out.npy", tmp_path / "ck.npz"
    proc = start(SLOW, "-o", out, "--spp", 64, "--workers", 2, "--chunk-size", 2000,
                 "--checkpoint", ck, "--checkpoint-interval", "0.01")
    wait_for(ck)
    workers = children_of(proc.pid)
    assert workers
    os.kill(workers[0], signal.SIGKILL)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 0, err
    np.testing.assert_array_equal(np.load(out), np.load(reference))


def test_a_signal_before_any_sample_is_finished_writes_nothing(tmp_path, monkeypatch, capsys):
    import importlib

    from wavefront import cli

    render_module = importlib.import_module("wavefront.render")
    out = tmp_path / "out.png"
    out.write_bytes(b"precious")
    real = render_module._run_inline

    def signalled_at_once(*args):
        os.kill(os.getpid(), signal.SIGTERM)  # arrives as the render starts
        return real(*args)

    monkeypatch.setattr(render_module, "_run_inline", signalled_at_once)
    status = cli.main(["render", str(SCENES / "three_spheres.yaml"), "-o", str(out), "--workers", "1"])
    err = capsys.readouterr().err
    assert status == 128 + signal.SIGTERM and "nothing was written" in err and "Traceback" not in err
    assert out.read_bytes() == b"precious"

    def signalled_while_compiling(scene, memory):
        os.kill(os.getpid(), signal.SIGTERM)
        raise AssertionError("the signal should have ended the command")

    monkeypatch.setattr(render_module, "compile_within", signalled_while_compiling)
    status = cli.main(["render", str(SCENES / "three_spheres.yaml"), "-o", str(out), "--workers", "1"])
    assert status == 128 + signal.SIGTERM and out.read_bytes() == b"precious"



def test_workers_that_keep_dying_end_the_render_with_one_message(monkeypatch):
    """Each task kills its worker: after MAX_WORKER_DEATHS replacements the
    render gives up with a RenderError naming the cause, instead of looping."""
    render_module = importlib.import_module("wavefront.render")  # the module (wavefront.render is the function)
    if "fork" not in __import__("multiprocessing").get_all_start_methods():
        pytest.skip("the patched task reaches the workers by fork")
    monkeypatch.setattr(render_module, "run_stream", lambda task, receive, deliver, ask=None: os._exit(3))
    scene = load_scene(SCENES / "three_spheres.yaml").with_overrides(width=64, height=64,
                                                                              samples_per_pixel=8)
    with pytest.raises(render_module.RenderError, match=r"worker processes died \(exit status 3\)"):
        render_module.render_scene(scene, workers=2, chunk_size=512)


def test_a_worker_killed_on_the_renders_last_task_costs_only_that_task(tmp_path, monkeypatch):
    """The last task is sent as its worker's last (it exits once its result
    is sent); killed before that, the worker is a death like any other: the
    task runs again on a new worker and the image is the undisturbed one."""
    render_module = importlib.import_module("wavefront.render")  # the module (wavefront.render is the function)
    if "fork" not in __import__("multiprocessing").get_all_start_methods():
        pytest.skip("the patched task reaches the workers by fork")
    scene = load_scene(SCENES / "three_spheres.yaml").with_overrides(width=48, height=32, samples_per_pixel=4)
    expected = render_scene(scene, workers=1, chunk_size=256).image
    last_unit = len(render_module.UnitPlan(48, 32, 4)) - 1
    marker, real = tmp_path / "killed", render_module.run_stream

    def dies_once_on_the_last_task(task, receive, deliver, ask=None):
        """The worker's tasks, the first and those its wavefront runs on into, checked as they come."""
        def check(units):
            if units is not None and units[-1].index == last_unit and not marker.exists():
                marker.touch()
                os._exit(9)
            return units

        return real(check(task), lambda: check(receive()), deliver, ask)

    monkeypatch.setattr(render_module, "run_stream", dies_once_on_the_last_task)
    result = render_scene(scene, workers=2, chunk_size=256)
    assert marker.exists() and np.array_equal(result.image, expected)


def test_workers_retired_for_want_of_work_are_not_deaths():
    """Six workers, each retired as the plan runs out: more exits than
    MAX_WORKER_DEATHS, none of them a death, and none outlives the render."""
    render_module = importlib.import_module("wavefront.render")
    scene = load_scene(SCENES / "three_spheres.yaml").with_overrides(width=64, height=48, samples_per_pixel=32)
    expected = render_scene(scene, workers=1, chunk_size=256).image
    # a budget that fits six copies of this (test) process, whatever it holds
    memory = min(8 << 30, render_module.physical_memory())
    result = render_scene(scene, workers=6, chunk_size=256, memory=memory)
    if result.stats.workers <= render_module.MAX_WORKER_DEATHS:
        pytest.skip(f"{memory >> 20} MiB fit only {result.stats.workers} workers")
    assert result.stats.workers == 6
    assert np.array_equal(result.image, expected)
    assert not __import__("multiprocessing").active_children()


def test_a_worker_that_exits_after_its_last_result_is_not_a_death(monkeypatch):
    """A worker sent its last task exits once its result is sent, which may be
    after the parent took its list of ready pipes (here: a should_stop that
    takes a while, polled after each wait): its result is read, not lost
    with the worker counted dead and the task run again."""
    render_module = importlib.import_module("wavefront.render")
    scene = load_scene(SCENES / "three_spheres.yaml").with_overrides(width=64, height=48, samples_per_pixel=8)
    expected = render_scene(scene, workers=1, chunk_size=256).image
    deaths, real_bury = [], render_module._Workers.bury

    def bury(self, worker, replace):
        deaths.append(list(worker.tasks))
        return real_bury(self, worker, replace)

    monkeypatch.setattr(render_module._Workers, "bury", bury)

    def slow_stop():
        time.sleep(0.1)
        return False

    for _ in range(3):
        result = render_scene(scene, workers=2, chunk_size=256, should_stop=slow_stop)
        assert np.array_equal(result.image, expected)
    assert deaths == []


def test_a_task_error_in_a_worker_is_raised_in_the_parent(monkeypatch):
    render_module = importlib.import_module("wavefront.render")  # the module (wavefront.render is the function)
    if "fork" not in __import__("multiprocessing").get_all_start_methods():
        pytest.skip("the patched task reaches the workers by fork")

    def failing(task, receive, deliver, ask=None):
        raise ValueError(f"task of {len(task)} units failed")

    monkeypatch.setattr(render_module, "run_stream", failing)
    scene = load_scene(SCENES / "three_spheres.yaml").with_overrides(width=64, height=64,
                                                                              samples_per_pixel=8)
    with pytest.raises(ValueError, match="units failed") as raised:
        render_module.render_scene(scene, workers=2, chunk_size=512)
    # where it failed, in the worker: its traceback is the error's cause
    assert isinstance(raised.value.__cause__, render_module.WorkerTraceback)
    assert "in failing" in str(raised.value.__cause__)


def test_a_process_forked_after_a_render_renders_on_workers_of_its_own(tmp_path):
    """Nothing of the parent's finished render (its worker processes) is left
    for a forked child to wait for: the child's own pooled render works."""
    if "fork" not in __import__("multiprocessing").get_all_start_methods():
        pytest.skip("forks")
    scene = load_scene(SCENES / "three_spheres.yaml").with_overrides(width=48, height=32, samples_per_pixel=4)
    expected = render_scene(scene, workers=2, chunk_size=256).image
    pid = os.fork()
    if pid == 0:  # the child: render on its own workers, report by exit status
        try:
            same = np.array_equal(render_scene(scene, workers=2, chunk_size=256).image, expected)
        except BaseException:
            os._exit(2)
        os._exit(0 if same else 1)
    _, status = os.waitpid(pid, 0)
    assert os.waitstatus_to_exitcode(status) == 0


def test_no_worker_process_outlives_a_render():
    scene = load_scene(SCENES / "three_spheres.yaml").with_overrides(width=48, height=32, samples_per_pixel=4)
    before = set(children_of(os.getpid())) if os.path.isdir("/proc") else set()  # other tests' (a dask cluster)
    render_scene(scene, workers=3, chunk_size=256)
    assert not __import__("multiprocessing").active_children()
    if os.path.isdir("/proc"):
        assert set(children_of(os.getpid())) <= before  # not even a zombie


def test_sigterm_ends_a_forked_child_that_still_has_the_commands_handler():
    """A worker forked before its initializer resets the signal handlers
    runs the command's handler: a SIGTERM must still end it."""
    from wavefront.cli import _Signals

    handler = _Signals()
    handler.rendering = True
    previous = signal.signal(signal.SIGTERM, handler)
    try:
        pid = os.fork()
        if pid == 0:  # the child: wait to be terminated
            time.sleep(30)
            os._exit(0)
        time.sleep(0.1)
        os.kill(pid, signal.SIGTERM)
        deadline = time.monotonic() + 10
        while time.monotonic() < deadline:
            done, status = os.waitpid(pid, os.WNOHANG)
            if done:
                break
            time.sleep(0.05)
        else:
            os.kill(pid, signal.SIGKILL)
            os.waitpid(pid, 0)
            pytest.fail("the child caught SIGTERM and went on")
        assert os.WIFSIGNALED(status) and os.WTERMSIG(status) == signal.SIGTERM
        assert handler.stop is None  # the parent's render was not asked to stop
    finally:
        signal.signal(signal.SIGTERM, previous)
