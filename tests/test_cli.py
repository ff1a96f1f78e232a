"""The command line, run as a user would run it."""

import os
import subprocess
import sys
import time

import numpy as np
import pytest

from wavefront.output import read_png_metadata

from .test_furnace import SCENES


def run(*args, cwd=None):
    return subprocess.run([sys.executable, "-m", "wavefront", *map(str, args)],
                          capture_output=True, text=True, cwd=cwd, timeout=300)


SMALL = ("--width", 32, "--height", 18, "--spp", 2, "--max-depth", 5)


@pytest.mark.parametrize("ext", ["png", "exr", "npy"])
def test_writes_each_format_with_the_right_shape(tmp_path, ext):
    out = tmp_path / f"img.{ext}"
    r = run("render", SCENES / "three_spheres.yaml", "-o", out, *SMALL, "--workers", 1)
    assert r.returncode == 0, r.stderr
    if ext == "npy":
        image = np.load(out)
        assert image.shape == (18, 32, 3) and image.dtype == np.float32
    elif ext == "exr":
        import OpenEXR

        with OpenEXR.File(str(out), separate_channels=True) as f:
            assert sorted(f.channels()) == ["B", "G", "R"]
            assert f.channels()["R"].pixels.shape == (18, 32)
            assert f.header()["wavefront.seed"] == "1"
    else:
        import imageio.v3 as iio

        image = iio.imread(out)
        assert image.shape == (18, 32, 3) and image.dtype == np.uint8
        meta = read_png_metadata(out)
        assert meta["wavefront.seed"] == "1" and meta["wavefront.scene"] == "three_spheres"
    assert not list(tmp_path.glob(".wavefront-*")), "temporary file left behind"


def test_summary_line_and_formats_agree(tmp_path):
    r = run("render", SCENES / "three_spheres.yaml", "-o", tmp_path / "a.npy", *SMALL, "--seed", 9)
    assert r.returncode == 0, r.stderr
    line = r.stderr.strip().splitlines()[-1]
    for needle in (" s,", "samples/s", "path segments/s", "peak memory", "seed 9"):
        assert needle in line, line
    png = run("render", SCENES / "three_spheres.yaml", "-o", tmp_path / "a.png", *SMALL, "--seed", 9, "-q")
    assert png.returncode == 0 and png.stderr == ""
    import imageio.v3 as iio

    from wavefront.output import encode_srgb8

    np.testing.assert_array_equal(iio.imread(tmp_path / "a.png"), encode_srgb8(np.load(tmp_path / "a.npy")))


def test_width_alone_keeps_the_aspect_ratio(tmp_path):
    r = run("render", SCENES / "three_spheres.yaml", "-o", tmp_path / "w.npy", "--width", 80, "--spp", 1, "-q")
    assert r.returncode == 0, r.stderr
    assert np.load(tmp_path / "w.npy").shape == (45, 80, 3)


def bad_scene(tmp_path, text):
    p = tmp_path / "bad.yaml"
    p.write_text(text)
    return p


@pytest.mark.parametrize("text,needle", [
    ("spheres:\n  - {center: [0,0,0], radius: 1, material: nope}\n", "spheres[0].material"),
    ("spheres: [\n", "invalid YAML"),
    ("image: {width: -3}\nspheres: []\n", "image.width"),
])
def test_bad_scene_exits_2_with_one_message_and_no_output(tmp_path, text, needle):
    out = tmp_path / "out.png"
    out.write_bytes(b"precious")  # must not be clobbered
    r = run("render", bad_scene(tmp_path, text), "-o", out)
    assert r.returncode == 2
    assert "Traceback" not in r.stderr and needle in r.stderr and "bad.yaml" in r.stderr
    assert len(r.stderr.strip().splitlines()) == 1
    assert out.read_bytes() == b"precious"


@pytest.mark.parametrize("args,needle", [
    (("--spp", "0"), "--spp"),
    (("--width", "abc"), "--width"),
    (("--seed", "-4"), "--seed"),
    # flags obey the scene file's own limits
    (("--max-depth", "10001"), "--max-depth"),
    (("--spp", str(2**30)), "--spp"),
    (("--width", "1000000", "--height", "1000000"), "pixels"),
    (("--memory", "100T"), "machine's memory"),
    (("--memory", "1M"), "--memory"),
    (("--memory", "100ib"), "--memory"),
    (("--memory", "9" * 400), "--memory"),
    (("--spp", "1_000"), "--spp"),
    (("--workers", str(2**31)), "--workers"),
    (("--frames", str(2**31)), "--frames"),
    (("--sampler", "halton"), "--sampler"),
])
def test_bad_arguments_exit_2(tmp_path, args, needle):
    r = run("render", SCENES / "three_spheres.yaml", "-o", tmp_path / "x.png", *args)
    assert r.returncode == 2 and needle in r.stderr and "Traceback" not in r.stderr
    assert len(r.stderr.strip().splitlines()) == 1
    assert not (tmp_path / "x.png").exists()


@pytest.mark.parametrize("args,named", [
    (("--height", "200000000"), "--height 200000000: an image of 355555556x200000000"),  # the width follows
    (("--height", "2000000"), "--height 2000000: "),
    (("--width", "200000000"), "--width 200000000: "),
    (("--height", "300000000"), "--height: "),  # past the limit of one side: argparse's own message
])
def test_a_too_large_side_names_the_flag_given(tmp_path, args, named):
    """--height alone used to be reported as "image: must be <= 268435456" of the width it implied."""
    out = tmp_path / "x.png"
    out.write_bytes(b"precious")
    r = run("render", SCENES / "three_spheres.yaml", "-o", out, *args)
    assert r.returncode == 2 and named in r.stderr and "Traceback" not in r.stderr, r.stderr
    assert len(r.stderr.strip().splitlines()) == 1
    assert out.read_bytes() == b"precious"


@pytest.mark.parametrize("name,needle", [("x.jpg", "unknown output extension"),
                                         ("missing/dir/x.png", "does not exist"),
                                         ("/proc/wavefront-test.png", "cannot write")])  # absolute: replaces tmp_path
def test_bad_output_path_is_reported_before_rendering(tmp_path, name, needle):
    if name.startswith("/proc") and not os.path.isdir("/proc"):
        pytest.skip("no /proc here")
    start = time.monotonic()
    r = run("render", SCENES / "three_spheres.yaml", "-o", tmp_path / name)  # 100 spp: seconds if it rendered
    assert r.returncode == 2 and needle in r.stderr and "Traceback" not in r.stderr
    assert "samples/s" not in r.stderr and time.monotonic() - start < 30


def test_version():
    r = run("--version")
    assert r.returncode == 0 and r.stdout.startswith("wavefront ") and r.stdout.split()[1][0].isdigit()


def test_version_is_the_installed_packages():
    """The command reads wavefront.__version__ (importlib.metadata costs ~15 ms a
    run); pyproject.toml takes the version from there, so the two agree."""
    from importlib.metadata import version

    assert run("--version").stdout.split()[1] == version("wavefront")


def test_summary_gives_render_and_total_time(tmp_path):
    r = run("render", SCENES / "three_spheres.yaml", "-o", tmp_path / "a.png", *SMALL)
    assert r.returncode == 0, r.stderr
    line = r.stderr.strip().splitlines()[-1]
    render = float(line.split("render ")[1].split(" s")[0])
    total = float(line.split("total ")[1].split(" s")[0])
    load = float(line.split("load ")[1].split(" s")[0])
    write = float(line.split("write ")[1].split(" s")[0])
    # the total runs from the process's start: interpreter, imports, loading, rendering and writing
    assert total >= render + load + write and write > 0


def test_distributed_is_reachable_after_import_wavefront():
    r = subprocess.run([sys.executable, "-c", "import wavefront; print(wavefront.distributed.dask_executor.__name__)"],
                       capture_output=True, text=True)
    assert r.returncode == 0 and r.stdout.strip() == "dask_executor", r.stderr


def test_a_small_budget_uses_fewer_workers_or_refuses_with_the_estimate(tmp_path):
    r = run("render", SCENES / "three_spheres.yaml", "-o", tmp_path / "a.npy", "--width", 400, "--spp", 4,
            "--max-depth", 5, "--workers", 2, "--memory", "64M")
    assert r.returncode == 0, r.stderr
    line = r.stderr.strip().splitlines()[-1]
    assert line.endswith(", 1 worker") and int(line.split("peak memory ")[1].split()[0]) <= 64, line
    r = run("render", SCENES / "three_spheres.yaml", "-o", tmp_path / "big.npy", "--width", 6000, "--height", 4000,
            "--memory", "64M")
    assert r.returncode == 2 and "needs about" in r.stderr and "MiB" in r.stderr and "Traceback" not in r.stderr
    assert not (tmp_path / "big.npy").exists()


def test_memory_sizes_in_every_spelling(tmp_path):
    from wavefront.cli import _memory

    assert _memory("1073741824") == _memory("1073741824B") == _memory("1G") == _memory("1GiB") == 1 << 30
    assert _memory("1.5g") == 3 << 29 and _memory("512mb") == 512 << 20


def test_the_python_api_checks_its_arguments_like_the_flags():
    from wavefront import Lambertian, Scene, Sphere, render_scene

    scene = Scene(spheres=[Sphere((0, 0, -1), 0.5, "m")], materials={"m": Lambertian()}, width=4, height=3)
    for bad in (dict(memory=100 << 40), dict(memory="1G"), dict(memory=-1), dict(workers=0), dict(workers=2.5),
                dict(chunk_size=0), dict(chunk_size=-5), dict(checkpoint_interval=float("nan")),
                dict(checkpoint_interval=-1)):
        with pytest.raises(ValueError):
            render_scene(scene, **bad)
    for bad in (dict(progress=5), dict(should_stop=True), dict(executor=5)):
        with pytest.raises(TypeError):
            render_scene(scene, **bad)


def test_many_frames_are_checked_in_linear_time(tmp_path):
    from types import SimpleNamespace

    from wavefront.cli import check_paths

    args = SimpleNamespace(output=str(tmp_path / "f{frame:05d}.npy"), frames=20_000, checkpoint=None, resume=None,
                           scene=str(SCENES / "three_spheres.yaml"))
    start = time.monotonic()
    assert len(check_paths(args)) == 20_000
    # quadratic took 41 s for 2,000 frames, so 20,000 would take over an hour;
    # linear takes a second or two, and the margin absorbs a loaded CI machine
    assert time.monotonic() - start < 120


def test_a_nul_byte_in_a_frame_name_is_one_line(tmp_path):
    r = run("render", SCENES / "three_spheres.yaml", "-o", str(tmp_path / "f{frame:c}.png"), "--frames", 2, *SMALL)
    assert r.returncode == 2 and "NUL" in r.stderr and "Traceback" not in r.stderr


def test_an_existing_checkpoint_is_not_overwritten_without_resume(tmp_path):
    ck = tmp_path / "ck.npz"
    assert run("render", SCENES / "three_spheres.yaml", "-o", tmp_path / "a.npy", "--checkpoint", ck, *SMALL,
               "-q").returncode == 0
    before = ck.read_bytes()
    r = run("render", SCENES / "three_spheres.yaml", "-o", tmp_path / "b.npy", "--checkpoint", ck, *SMALL)
    assert r.returncode == 2 and "--resume" in r.stderr and ck.read_bytes() == before
    r = run("render", SCENES / "three_spheres.yaml", "-o", tmp_path / "b.npy", "--checkpoint", ck, "--resume", ck,
            *SMALL, "-q")
    assert r.returncode == 0, r.stderr


def test_sampler_flag_overrides_the_scene_and_is_recorded(tmp_path):
    images = {}
    for sampler in ("sobol", "independent"):
        out = tmp_path / f"{sampler}.png"
        r = run("render", SCENES / "three_spheres.yaml", "-o", out, *SMALL, "--sampler", sampler, "--workers", 1, "-q")
        assert r.returncode == 0, r.stderr
        assert read_png_metadata(out)["wavefront.sampler"] == sampler
        images[sampler] = out.read_bytes()
    assert images["sobol"] != images["independent"]


def _numpy_blas() -> str:
    """The name of the BLAS this NumPy was built with ("" if it does not say)."""
    try:
        return str(np.show_config(mode="dicts")["Build Dependencies"]["blas"]["name"])
    except Exception:  # noqa: BLE001 (an older NumPy, another layout: unknown)
        return ""


@pytest.mark.skipif(not os.path.isdir("/proc/self/task") or len(getattr(os, "sched_getaffinity", lambda _: ())(0)) < 2
                    or "openblas" not in _numpy_blas(),
                    reason="counts OpenBLAS's threads through Linux's /proc, on at least two usable cores")
@pytest.mark.parametrize("chosen", [None, ("OPENBLAS_NUM_THREADS", "2"), ("OMP_NUM_THREADS", "2")])
def test_importing_wavefront_first_starts_no_blas_threads_unless_the_user_chose(chosen):
    """A command's NumPy runs one thread (OpenBLAS's pool spun on the other
    core at every start); a thread count the user set is kept, and OpenBLAS
    then starts its threads (so the count can tell)."""
    env = {k: v for k, v in os.environ.items() if k not in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS")}
    if chosen is not None:
        env[chosen[0]] = chosen[1]
    code = ("import os, glob, wavefront; "
            "print(os.environ.get('OPENBLAS_NUM_THREADS', '-'), len(glob.glob(f'/proc/{os.getpid()}/task/*')))")
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True).stdout
    setting, threads = out.split()
    if chosen is None:
        assert (setting, threads) == ("1", "1")
    else:
        assert setting == (chosen[1] if chosen[0] == "OPENBLAS_NUM_THREADS" else "-") and int(threads) > 1
