"""The policy for every file wavefront writes: only regular files are replaced,
symlinks are written through, read-only files are left alone, modes are kept.

Special files are made in a temporary folder (a FIFO, a directory, a Unix
socket), never taken from the machine's own /dev."""

import os
import socket
import stat

import numpy as np
import pytest

from wavefront.film import Film, save_checkpoint
from wavefront.output import OutputError, check_output_path, remove_stale_temporaries, same_file, write_image
from wavefront.scene import Scene

from .test_cli import SMALL, run
from .test_furnace import SCENES

IMAGE = np.full((4, 5, 3), 0.25, dtype=np.float32)


def special_files(tmp_path):
    fifo = tmp_path / "fifo.png"
    os.mkfifo(fifo)
    directory = tmp_path / "dir.png"
    directory.mkdir()
    sock_path = tmp_path / "sock.png"
    sock = socket.socket(socket.AF_UNIX)
    sock.bind(str(sock_path))
    return {"a FIFO": fifo, "a directory": directory, "a socket": sock_path}, sock


def test_special_files_are_refused_before_and_at_the_write(tmp_path):
    files, sock = special_files(tmp_path)
    try:
        for kind, path in files.items():
            with pytest.raises(OutputError, match=kind):
                check_output_path(str(path))
            with pytest.raises(OutputError, match=kind):
                write_image(str(path), IMAGE)
            assert not stat.S_ISREG(os.lstat(path).st_mode)  # still what it was
            link = tmp_path / f"link-to-{path.name}"
            link.symlink_to(path)
            with pytest.raises(OutputError, match=kind):
                check_output_path(str(link))
    finally:
        sock.close()
    assert not list(tmp_path.glob(".wavefront-*")), "temporary file left behind"


def test_a_symlink_is_written_through_and_stays_a_link(tmp_path):
    target = tmp_path / "real.npy"
    np.save(target, np.zeros(1))
    link = tmp_path / "link.npy"
    link.symlink_to(target)
    write_image(str(link), IMAGE)
    assert link.is_symlink() and os.readlink(link) == str(target)
    np.testing.assert_array_equal(np.load(target), IMAGE)
    dangling = tmp_path / "dangling.npy"
    dangling.symlink_to(tmp_path / "not-yet.npy")
    write_image(str(dangling), IMAGE)
    np.testing.assert_array_equal(np.load(tmp_path / "not-yet.npy"), IMAGE)


def test_a_symlink_loop_is_refused(tmp_path):
    a, b = tmp_path / "a.png", tmp_path / "b.png"
    a.symlink_to(b)
    b.symlink_to(a)
    with pytest.raises(OutputError):
        check_output_path(str(a))


def test_read_only_files_are_never_overwritten_and_modes_are_kept(tmp_path):
    locked = tmp_path / "locked.npy"
    np.save(locked, np.zeros(1))
    locked.chmod(0o444)
    before = locked.read_bytes()
    with pytest.raises(OutputError, match="read-only"):
        check_output_path(str(locked))
    with pytest.raises(OutputError, match="read-only"):
        write_image(str(locked), IMAGE)  # even as root
    assert locked.read_bytes() == before and stat.S_IMODE(locked.stat().st_mode) == 0o444
    kept = tmp_path / "kept.npy"
    np.save(kept, np.zeros(1))
    kept.chmod(0o640)
    write_image(str(kept), IMAGE)
    assert stat.S_IMODE(kept.stat().st_mode) == 0o640
    np.testing.assert_array_equal(np.load(kept), IMAGE)


def test_same_file_sees_through_links(tmp_path):
    a = tmp_path / "a.png"
    a.write_bytes(b"x")
    (tmp_path / "hard.png").hardlink_to(a)
    (tmp_path / "soft.png").symlink_to(a)
    assert same_file(str(a), str(tmp_path / "hard.png")) and same_file(str(a), str(tmp_path / "soft.png"))
    assert same_file(str(tmp_path / "x" / ".." / "a.png"), str(a))
    assert not same_file(str(a), str(tmp_path / "b.png"))


def test_checkpoint_writes_follow_the_same_policy(tmp_path):
    files, sock = special_files(tmp_path)
    film = Film(2, 2)
    try:
        for kind, path in files.items():
            ck = path.with_suffix(".npz")
            os.rename(path, ck)
            with pytest.raises(OutputError, match=kind):
                save_checkpoint(str(ck), _tiny_scene(), film, 0)
    finally:
        sock.close()


def _tiny_scene():
    from wavefront import Lambertian, Sphere

    return Scene(spheres=[Sphere((0, 0, -1), 0.5, "m")], materials={"m": Lambertian()}, width=2, height=2)


# --- the command line ------------------------------------------------------------

@pytest.mark.parametrize("flag", ["-o", "--checkpoint"])
def test_cli_refuses_special_files_before_rendering(tmp_path, flag):
    fifo = tmp_path / ("fifo.npz" if flag == "--checkpoint" else "fifo.png")
    os.mkfifo(fifo)
    folder = fifo.with_name("folder" + fifo.suffix)
    folder.mkdir()
    for path in (fifo, folder):
        args = ["-o", tmp_path / "out.png", "--checkpoint", path] if flag == "--checkpoint" else ["-o", path]
        r = run("render", SCENES / "three_spheres.yaml", *args, *SMALL)
        assert r.returncode == 2, r.stderr
        assert len(r.stderr.strip().splitlines()) == 1 and "regular files" in r.stderr and "Traceback" not in r.stderr
        assert not (tmp_path / "out.png").exists() and stat.S_ISFIFO(os.lstat(fifo).st_mode)


def test_cli_refuses_one_file_named_twice_or_an_input_as_output(tmp_path):
    (tmp_path / "a.npy").write_bytes(b"")
    (tmp_path / "link.npz").symlink_to(tmp_path / "real.png")
    cases = [
        (["-o", tmp_path / "a.png", "--checkpoint", tmp_path / "a.png"], "must end in .npz"),
        (["-o", tmp_path / "real.png", "--checkpoint", tmp_path / "link.npz"], "name the same file"),
        (["-o", tmp_path / "a.npy", "--checkpoint", tmp_path / "ck.npz", "--resume", tmp_path / "a.npy"],
         "would overwrite --resume"),
        (["-o", tmp_path / "s{frame!s:.0}.png", "--frames", 3], "same file name"),
        (["-o", tmp_path / "a_{frame}.png"], "--frames was not given"),
    ]
    for args, needle in cases:
        r = run("render", SCENES / "three_spheres.yaml", *args, *SMALL)
        assert r.returncode == 2 and needle in r.stderr and "Traceback" not in r.stderr, (args, r.stderr)
        assert len(r.stderr.strip().splitlines()) == 1
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.npy", "link.npz"]


def test_stale_temporaries_of_dead_writers_are_removed(tmp_path):
    import subprocess
    import sys
    import time as clock

    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()
    old = clock.time() - 3600
    stale = [tmp_path / f".wavefront-checkpoint-{dead.pid}-abc_1234.npz", tmp_path / f".wavefront-{dead.pid}-a_c12345.exr",
             tmp_path / f".wavefront-probe-{dead.pid}-abcdefgh"]
    fresh = tmp_path / f".wavefront-{dead.pid}-defghijk.png"  # recent: maybe a writer on another machine
    alive = tmp_path / f".wavefront-{os.getpid()}-ghijklmn.png"  # its writer is running
    # not named exactly as wavefront names its temporary files: never touched
    others = [tmp_path / name for name in (".wavefront-notes.txt", f".wavefront-{dead.pid}-my-notes.txt",
                                           f".wavefront-{dead.pid}-abcdefgh.png.bak", f".wavefront-{dead.pid}-abc.png",
                                           f".wavefront-probe-{dead.pid}-abcdefgh.png")]
    for p in (*stale, fresh, alive, *others):
        p.write_bytes(b"x")
    for p in (*stale, alive, *others):
        os.utime(p, (old, old))
    remove_stale_temporaries(str(tmp_path))
    assert not any(p.exists() for p in stale) and fresh.exists() and alive.exists()
    assert all(p.exists() for p in others)


def test_a_full_disk_while_writing_an_exr_is_an_oserror(tmp_path, monkeypatch):
    """OpenEXR reports a failed write as RuntimeError; the CLI's rescue path catches OSError."""
    import OpenEXR

    class Full:
        def __init__(self, *args):
            pass

        def __enter__(self):
            return self

        def __exit__(self, *exc):
            return False

        def write(self, path):
            raise RuntimeError(f'Failed to write pixel data to image file "{path}". No space left on device.')

    monkeypatch.setattr(OpenEXR, "File", Full)
    with pytest.raises(OSError, match="No space left"):
        write_image(str(tmp_path / "x.exr"), IMAGE)
    assert not list(tmp_path.iterdir())


# --- 8-bit sRGB: the shipped table is colour-science's encoding ------------------

def _table_script():
    """wavefront/data/make_srgb8_thresholds.py, which computes the table with colour-science."""
    from wavefront.data import make_srgb8_thresholds

    return make_srgb8_thresholds


def test_the_srgb8_table_is_what_colour_science_gives_today():
    """Recomputed by bisection with the installed colour-science: a newer
    colour-science that changed its sRGB function would fail here."""
    from wavefront.output import srgb8_thresholds

    np.testing.assert_array_equal(_table_script().thresholds(), srgb8_thresholds())


def _neighbours(values: np.ndarray, dtype, reach: int) -> np.ndarray:
    """Every float of ``dtype`` within ``reach`` steps of each of ``values`` (positive)."""
    ints = {np.float64: np.int64, np.float32: np.int32}[dtype]
    bits = values.astype(dtype).view(ints)
    return (bits[:, None] + np.arange(-reach, reach + 1, dtype=ints)[None, :]).ravel().view(dtype)


@pytest.mark.parametrize("dtype", [np.float64, np.float32])
def test_encode_srgb8_is_colour_sciences_encoding_bit_for_bit(dtype):
    """Every threshold and thousands of float neighbours on each side (where a
    rounding difference would show), a dense and a random sweep of [-0.1, 1.1],
    and the special values, against colour-science's own function."""
    from wavefront.output import encode_srgb8, srgb8_thresholds

    reference = _table_script().colour_srgb8
    thresholds = srgb8_thresholds()
    rng = np.random.default_rng(5)
    special = np.array([np.nan, -np.nan, np.inf, -np.inf, 0.0, -0.0, -1e-300, 5e-324, -5e-324, 1e-45,
                        np.finfo(dtype).tiny, 0.0031308, 1.0, np.nextafter(1.0, 2.0), 1.5, -1.0, 1e30,
                        -1e30, np.finfo(dtype).max, -np.finfo(dtype).max], dtype=dtype)
    values = np.concatenate([
        _neighbours(thresholds, dtype, 2048), special, np.linspace(-0.1, 1.1, 1_000_001, dtype=dtype),
        rng.random(1_000_000).astype(dtype), (rng.random(100_000) * 0.01).astype(dtype)])
    values = values[: values.size // 3 * 3]
    image = values.reshape(-1, 1, 3)  # (H, 1, 3): many strips of ENCODE_ROWS rows
    np.testing.assert_array_equal(encode_srgb8(image), reference(image))
    # codes step exactly at the thresholds
    codes = encode_srgb8(np.repeat(thresholds[:, None, None], 3, axis=2))[:, 0, 0]
    below = encode_srgb8(np.repeat(np.nextafter(thresholds, 0)[:, None, None], 3, axis=2))[:, 0, 0]
    np.testing.assert_array_equal(codes, np.arange(1, 256))
    np.testing.assert_array_equal(below, np.arange(0, 255))


def test_a_png_is_written_without_importing_colour_science(tmp_path):
    """The point of the table: colour-science costs ~0.7 s and ~90 MiB to import."""
    import subprocess
    import sys

    code = ("import sys, numpy as np; from wavefront.output import write_image; "
            f"write_image({str(tmp_path / 'x.png')!r}, np.full((3, 4, 3), 0.5, np.float32)); "
            "print('colour' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"
    import imageio.v3 as iio

    assert (iio.imread(tmp_path / "x.png") == 188).all()  # rint(255 * 0.735357)


def test_an_empty_output_path_is_named_as_empty(tmp_path):
    """``-o ''`` read "wavefront: error: : unknown output extension '(none)'"."""
    r = run("render", SCENES / "three_spheres.yaml", "-o", "", cwd=tmp_path)
    assert r.returncode == 2 and r.stderr.strip().splitlines() == [
        "wavefront: error: the output path is empty; expected a file name ending in one of: .png, .exr, .npy"], r.stderr
    assert not list(tmp_path.iterdir())


@pytest.mark.parametrize("path,problem", [
    (" ", "the output path ' ' is blank"), ("\t", "the output path '\\t' is blank"),
    ("./", "./: names a directory, not a file"), ("/", "/: names a directory, not a file"),
    ("..", "..: names a directory, not a file")])
def test_a_blank_or_directory_output_path_is_named_as_such(tmp_path, path, problem):
    """``-o ' '``, ``-o ./``, ``-o /`` read "error:  : unknown output extension '(none)'"."""
    r = run("render", SCENES / "three_spheres.yaml", "-o", path, cwd=tmp_path)
    assert r.returncode == 2 and r.stderr.strip().splitlines() == [
        f"wavefront: error: {problem}; expected a file name ending in one of: .png, .exr, .npy"], r.stderr
    assert not list(tmp_path.iterdir())
