"""Writing images (PNG 8-bit sRGB, EXR linear float, NPY linear float32) and
the policy every file the renderer writes follows.

* Everything is written to a temporary file in the destination's directory
  and renamed over the target only when complete, so a failed or interrupted
  write never leaves a half-written or clobbered file.
* Only regular files are ever replaced.  A FIFO, a device node, a socket or a
  directory at the destination is refused before rendering, and again just
  before the rename.
* A symlink is written *through*: its target is replaced and the link stays
  (as ``cp`` and shell redirection do).
* A read-only file (no write bit for anyone) is never overwritten, even by
  root: making a file read-only is how a user protects it.  An existing
  writable file keeps its permission bits (and, for root, its owner).
* :func:`check_output_path` runs before rendering so a bad destination is
  reported in a second, not after an hour of rendering.
"""

from __future__ import annotations

import contextlib
import errno
import functools
import os
import re
import stat
import tempfile
import time

import numpy as np

FORMATS = (".png", ".exr", ".npy")
ENCODE_ROWS = 256  # encode in strips of rows to bound peak memory

# Bytes per pixel the parent holds while writing each format, on top of the
# film (measured with ``benchmarks/bench.py --section budget``): PNG keeps the
# 8-bit image and Pillow's 4-byte-per-pixel copy of it; EXR the float32 image
# and OpenEXR's per-channel copy; NPY streams rows from the film.
ENCODE_BYTES_PER_PIXEL = {".png": 3 + 4, ".exr": 12 + 12, ".npy": 0}
# Importing Pillow and its PNG plugin (PNG only) maps this much: ~10 MiB
# measured with Pillow 13 on top of NumPy and wavefront, plus room for versions.
# (Encoding through colour-science at run time cost ~90 MiB: see SRGB8_THRESHOLDS.)
PNG_IMPORT_BYTES = 16 << 20
# Strip temporaries: float64 RGB rows, their int64 buckets, the gathered
# float64 thresholds, and one copy to spare.
STRIP_BYTES_PER_PIXEL = 4 * 3 * 8
# colour-science's 8-bit sRGB encoding as the 255 linear values where its
# code steps, generated (and checked by tests/test_output.py) with
# colour-science itself by data/make_srgb8_thresholds.py: encoding a PNG
# without importing colour-science saves ~0.7 s and ~90 MiB per command.
SRGB8_THRESHOLDS = os.path.join(os.path.dirname(os.path.abspath(__file__)), "data", "srgb8_thresholds.txt")


class OutputError(ValueError):
    """An output path cannot or must not be written."""


def output_format(path: str) -> str:
    expected = f"expected a file name ending in one of: {', '.join(FORMATS)}"
    if not path:  # "-o ''" read ": unknown output extension '(none)'", naming no path
        raise OutputError(f"the output path is empty; {expected}")
    if not path.strip():  # "-o ' '" read " : unknown output extension '(none)'"
        raise OutputError(f"the output path {path!r} is blank; {expected}")
    if os.path.basename(path) in ("", ".", ".."):  # "-o ./", "-o /": a directory, not a file
        raise OutputError(f"{path}: names a directory, not a file; {expected}")
    ext = os.path.splitext(path)[1].lower()
    if not ext and os.path.basename(path).startswith("."):
        raise OutputError(f"{path}: has no extension (a name starting with a dot is a hidden file's name); "
                          f"expected one of: {', '.join(FORMATS)}")
    if ext not in FORMATS:
        raise OutputError(f"{path}: unknown output extension {ext or '(none)'!r} "
                          f"(expected one of: {', '.join(FORMATS)})")
    return ext


def encode_bytes(width: int, height: int, path: str) -> int:
    """Peak bytes the parent needs to write a ``width`` x ``height`` image to ``path``."""
    ext = output_format(path)
    strip = min(height, ENCODE_ROWS) * width * STRIP_BYTES_PER_PIXEL
    extra = PNG_IMPORT_BYTES if ext == ".png" else 0
    return width * height * ENCODE_BYTES_PER_PIXEL[ext] + strip + extra


def resolve_target(path: str) -> str:
    """The file a write to ``path`` replaces: symlinks followed, absolute."""
    return os.path.realpath(path)


_KINDS = ((stat.S_ISDIR, "a directory"), (stat.S_ISFIFO, "a FIFO"), (stat.S_ISCHR, "a character device"),
          (stat.S_ISBLK, "a block device"), (stat.S_ISSOCK, "a socket"))


def _refuse_unless_replaceable(path: str, st: os.stat_result) -> None:
    if not stat.S_ISREG(st.st_mode):
        kind = next((name for test, name in _KINDS if test(st.st_mode)), "not a regular file")
        raise OutputError(f"{path}: is {kind}; wavefront only ever replaces regular files")
    if not st.st_mode & 0o222:
        raise OutputError(f"{path}: is read-only (mode {stat.S_IMODE(st.st_mode):o}); wavefront does not "
                          "overwrite read-only files: make it writable or remove it first")


def check_output_path(path: str, *, image: bool = True, probe: bool = True) -> str:
    """Fail early if ``path`` cannot or must not be written; return its target.

    ``image`` checks the extension is an image format.  The directory is
    probed (unless ``probe`` is false, for a directory already probed) by
    creating and removing a temporary file there, the same way the file will
    be written: permission bits alone do not tell (root passes ``os.access``
    on read-only mounts and in ``/proc``).  Nothing else in the directory is
    touched (see :func:`remove_stale_temporaries`).
    """
    if image:
        output_format(path)
    if "\0" in path:
        raise OutputError(f"{path!r}: a file name cannot contain a NUL byte")
    target = resolve_target(path)
    try:
        st = os.stat(target)
    except FileNotFoundError:
        st = None
    except OSError as e:
        raise OutputError(f"{path}: {e.strerror or e}") from None
    if st is not None:
        _refuse_unless_replaceable(path, st)
        _refuse_if_immutable(path, target)
    directory = os.path.dirname(target)
    if not os.path.isdir(directory):
        raise OutputError(f"{path}: directory {directory} does not exist")
    if probe:
        try:
            fd, tmp = tempfile.mkstemp(prefix=temporary_prefix("probe"), dir=directory)
        except OSError as e:
            raise OutputError(f"{path}: cannot write in {directory} ({e.strerror or e})") from None
        os.close(fd)
        os.unlink(tmp)
    return target


def temporary_prefix(kind: str = "") -> str:
    """Name prefix of a temporary file this process writes: ``.wavefront-[kind-]PID-``."""
    return f".wavefront-{kind + '-' if kind else ''}{os.getpid()}-"


# Exactly the names this module and film.save_checkpoint give temporary
# files: tempfile.mkstemp's 8 characters after the prefix, and the suffix
# each kind is written with (an image's extension, a checkpoint's .npz, none
# for a probe).  Nothing else, however it starts, is ever removed.
_RANDOM = "[a-z0-9_]{8}"
_TEMPORARY = re.compile(rf"\.wavefront-(?:([0-9]+)-{_RANDOM}\.(?:png|exr|npy)|checkpoint-([0-9]+)-{_RANDOM}\.npz"
                        rf"|probe-([0-9]+)-{_RANDOM})")  # whole names only (fullmatch)
STALE_SECONDS = 600  # a temporary file untouched this long, whose writer is gone, is garbage


def remove_stale_temporaries(directory: str) -> None:
    """Remove temporary files a killed wavefront left in ``directory``.

    ``kill -9`` during a write leaves its temporary file behind.  Only a
    regular file named exactly as wavefront names its temporary files
    (``.wavefront-[kind-]PID-XXXXXXXX.ext``) is a candidate, and the command
    calls this only once the scene and its arguments have been accepted.  One is
    removed only when its writer's process no longer exists *and* it has not
    been touched for ``STALE_SECONDS`` (a render on another machine writing
    to a shared directory has a process id that means nothing here, but it
    keeps its file fresh).
    """
    now = time.time()
    try:
        entries = list(os.scandir(directory))
    except OSError:
        return
    for entry in entries:
        m = _TEMPORARY.fullmatch(entry.name)
        if m is None:
            continue
        try:
            if not entry.is_file(follow_symlinks=False) or now - entry.stat().st_mtime < STALE_SECONDS:
                continue
            os.kill(int(next(g for g in m.groups() if g is not None)), 0)
        except ProcessLookupError:
            with contextlib.suppress(OSError):
                os.unlink(entry.path)
        except (OSError, OverflowError, ValueError):
            continue


_FS_IOC_GETFLAGS = 0x80086601  # Linux: a file's attribute flags (chattr)
_IMMUTABLE, _APPEND_ONLY = 0x10, 0x20


def _refuse_if_immutable(path: str, target: str) -> None:
    """Refuse a file marked immutable or append-only (``chattr +i``/``+a``):
    even root cannot replace it, which otherwise shows only after rendering."""
    try:
        import array
        import fcntl

        fd = os.open(target, os.O_RDONLY | os.O_NONBLOCK)
    except (ImportError, OSError):
        return
    try:
        flags = array.array("l", [0])
        fcntl.ioctl(fd, _FS_IOC_GETFLAGS, flags, True)
    except OSError:
        return  # a file system without attribute flags
    finally:
        os.close(fd)
    if flags[0] & (_IMMUTABLE | _APPEND_ONLY):
        raise OutputError(f"{path}: is marked {'immutable' if flags[0] & _IMMUTABLE else 'append-only'} "
                          "(chattr); wavefront cannot replace it")


def file_key(path: str):
    """What identifies the file ``path`` names, through symlinks and hard
    links: its device and inode if it exists, else its resolved path."""
    target = resolve_target(path)
    try:
        st = os.stat(target)
        return (st.st_dev, st.st_ino)
    except OSError:
        return target


def same_file(a: str, b: str) -> bool:
    """Whether two paths name one file (through symlinks and hard links)."""
    return file_key(a) == file_key(b)


@functools.cache
def srgb8_thresholds() -> np.ndarray:
    """(255,) float64: ``[k - 1]`` is the smallest linear value whose 8-bit
    sRGB code is ``k`` or more (see ``SRGB8_THRESHOLDS``)."""
    with open(SRGB8_THRESHOLDS) as f:
        table = np.array([float.fromhex(line) for line in f if line.strip() and not line.startswith("#")])
    if table.shape != (255,) or not np.all(np.diff(table) > 0):  # a damaged install, not a user's input
        raise RuntimeError(f"{SRGB8_THRESHOLDS}: not 255 increasing thresholds")
    table.flags.writeable = False
    return table


# The lookup: a float64's bits, shifted right by BUCKET_SHIFT, name a bucket
# of 2**(52 - BUCKET_SHIFT) = 4096 buckets per octave (non-negative floats'
# bits are ordered like their values).  The sRGB codes step at most once in
# such a bucket (checked when the buckets are built), so a code is the
# bucket's count of thresholds below it, plus one if the value reaches the
# bucket's threshold: two gathers and a compare per value, exact, ~5x faster
# than a binary search of the thresholds (np.searchsorted).
BUCKET_SHIFT = 40


@functools.cache
def _srgb8_buckets() -> tuple[int, np.ndarray, np.ndarray]:
    """(first bucket, codes below each bucket (uint8), each bucket's threshold or +inf)."""
    thresholds = srgb8_thresholds()
    first = int(thresholds[:1].view(np.int64)[0]) >> BUCKET_SHIFT
    last = int(np.array([1.0]).view(np.int64)[0]) >> BUCKET_SHIFT  # 1.0 and above: every threshold is below
    starts = (np.arange(first, last + 2, dtype=np.int64) << BUCKET_SHIFT).view(np.float64)
    below = np.searchsorted(thresholds, starts, side="left")  # thresholds < each bucket's start
    inside = below[1:] - below[:-1]
    if inside.max() > 1 or below[-2] != len(thresholds):  # a coarser shift, or another table
        raise RuntimeError("sRGB buckets hold more than one threshold each")
    split = np.where(inside == 1, thresholds[np.minimum(below[:-1], len(thresholds) - 1)], np.inf)
    return first, below[:-1].astype(np.uint8), split


def encode_srgb8(image: np.ndarray) -> np.ndarray:
    """Linear RGB (H, W, 3) -> 8-bit sRGB with colour-science's transfer function.

    Values are clamped to [0, 1] before encoding (no tone mapping), as in the
    books, and rounded to nearest; NaN encodes as 0.  ``image`` may also be a
    row source (see :func:`write_image`).  The codes are colour-science's
    ``rint(255 * cctf_encoding(x, function="sRGB"))`` bit for bit, looked up
    in :func:`srgb8_thresholds` instead of computed: a code is the number of
    thresholds at or below the value (below 0 that is none, from 1 on all
    255), found through buckets of the value's bits (``BUCKET_SHIFT``).
    """
    first, below, split = _srgb8_buckets()
    height, width, rows = _row_source(image)
    out = np.empty((height, width, 3), dtype=np.uint8)
    for r0 in range(0, height, ENCODE_ROWS):
        r1 = min(height, r0 + ENCODE_ROWS)
        strip = np.array(rows(r0, r1), dtype=np.float64)  # a copy: the caller's image is left alone
        np.nan_to_num(strip, copy=False, nan=0.0)  # NaN encodes as 0 (+-inf become +-max: 255 and 0)
        bucket = strip.view(np.int64) >> BUCKET_SHIFT
        bucket -= first
        # negative values (sign bit set) and those below the first threshold's
        # bucket land in bucket 0, where nothing reaches its threshold; 1 and above in the last
        np.clip(bucket, 0, len(below) - 1, out=bucket)
        code = below[bucket]
        code += strip >= split[bucket]
        out[r0:r1] = code
    return out


def _row_source(image):
    """(height, width, rows(y0, y1) -> float32 (rows, W, 3)) for an array or a film."""
    if isinstance(image, np.ndarray):
        return image.shape[0], image.shape[1], lambda a, b: image[a:b]
    return image.height, image.width, image.rows


def write_image(path: str, image, metadata: dict[str, str] | None = None) -> None:
    """Write a linear float image atomically, following the module's policy.

    ``image`` is an array of shape (H, W, 3) or a row source with
    ``height``, ``width`` and ``rows(y0, y1)`` (a :class:`~wavefront.film.Film`),
    which PNG and NPY encode strip by strip without the whole float image.
    ``metadata`` goes into PNG text chunks and EXR header attributes.
    """
    ext = output_format(path)
    metadata = {k: metadata_text(v) for k, v in (metadata or {}).items()}
    target = resolve_target(path)
    fd, tmp = tempfile.mkstemp(prefix=temporary_prefix(), suffix=ext, dir=os.path.dirname(target))
    try:
        with os.fdopen(fd, "wb") as f:
            if ext == ".npy":
                _write_npy(f, image)
            elif ext == ".png":
                _write_png(f, image, metadata)
        if ext == ".exr":
            _write_exr(tmp, image, metadata)
        publish(tmp, target, path)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        raise


# NUL ends a C string (OpenEXR's attributes) and is forbidden in PNG text
# chunks; the other C0 controls but tab and newline are "discouraged" there
_UNWRITABLE = re.compile("[\x00-\x08\x0b-\x1f\x7f]")


def metadata_text(value) -> str:
    """``str(value)`` as text every image format can hold: a file name's
    undecodable bytes (``os.fsdecode``'s surrogates, from a non-UTF-8 path)
    shown as ``\\xff``, NUL and other control characters as escapes.

    Valid text without control characters is unchanged; Pillow stores text
    that is not Latin-1 in an iTXt (UTF-8) chunk instead of tEXt.
    """
    text = str(value)
    try:
        data = text.encode("utf-8", "surrogateescape")  # the bytes a path's surrogates stand for
    except UnicodeEncodeError:  # a surrogate no decoding made
        data = text.encode("utf-8", "backslashreplace")
    text = data.decode("utf-8", "backslashreplace")
    return _UNWRITABLE.sub(lambda m: f"\\x{ord(m.group()):02x}", text)


def publish(tmp: str, target: str, shown: str | None = None) -> None:
    """Move a finished temporary file over ``target`` (a resolved path).

    Refuses, at the last moment too, to replace anything but a writable
    regular file; an existing file's permission bits (and owner, for root)
    carry over, a new one gets the usual ``0666 & ~umask``.
    """
    try:
        st = os.lstat(target)
    except FileNotFoundError:
        st = None
    if st is not None:
        _refuse_unless_replaceable(shown or target, st)
    # Opened for the fsync with mode 0600 first: mkstemp's 0600 less the umask
    # (0477) and the mode the file takes (an existing mode-0200 target's) may
    # have no read bit, and an open by name then fails even for root without
    # CAP_DAC_OVERRIDE; the owner may always chmod.  Syncing is durability
    # only: a file that cannot be opened for it is published unsynced, never lost.
    try:
        os.chmod(tmp, stat.S_IRUSR | stat.S_IWUSR)
        fd = os.open(tmp, os.O_RDONLY)
    except OSError:
        fd = None
    try:
        mode = stat.S_IMODE(st.st_mode) if st is not None else 0o666 & ~_umask()
        if fd is not None:
            os.fchmod(fd, mode)
        else:
            os.chmod(tmp, mode)
        if st is not None and os.geteuid() == 0:
            with contextlib.suppress(OSError):
                os.chown(tmp, st.st_uid, st.st_gid)
        # on disk before it takes the target's name: after a crash or power cut
        # the target is the old file or the whole new one, never an empty one
        if fd is not None:
            _fsync(fd)
    finally:
        if fd is not None:
            os.close(fd)
    os.replace(tmp, target)
    # the rename itself, where the directory can be opened (best-effort too)
    with contextlib.suppress(OSError):
        dfd = os.open(os.path.dirname(target), os.O_RDONLY | getattr(os, "O_DIRECTORY", 0))
        try:
            _fsync(dfd)
        finally:
            os.close(dfd)


def _fsync(fd: int) -> None:
    """``fsync`` a descriptor; a file system that cannot (EINVAL, ENOTSUP) is
    skipped.  Any other error (EIO: the data did not reach the disk) reaches
    the caller, whose rescue saves the image elsewhere."""
    try:
        os.fsync(fd)
    except OSError as e:
        if e.errno not in (errno.EINVAL, errno.ENOTSUP):
            raise


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def _write_npy(f, image) -> None:
    height, width, rows = _row_source(image)
    header = {"descr": np.lib.format.dtype_to_descr(np.dtype(np.float32)), "fortran_order": False,
              "shape": (height, width, 3)}
    np.lib.format.write_array_header_1_0(f, header)  # what np.save writes for such a header
    for r0 in range(0, height, ENCODE_ROWS):
        f.write(np.ascontiguousarray(rows(r0, min(height, r0 + ENCODE_ROWS)), dtype=np.float32).tobytes())


# zlib's fastest level, as OpenCV writes PNGs by default: a rendered image's
# noise leaves little for the slower levels to find.  W1's 400x225 image:
# 6 ms and 136 KB, against 22 ms and 117 KB at Pillow's default level 6
# (written after the render, on one core: ~1 % of W1's command).
PNG_COMPRESS_LEVEL = 1


def _write_png(f, image, metadata) -> None:
    # Pillow's PNG writer, called as imageio calls it but at PNG_COMPRESS_LEVEL,
    # without imageio: its writer makes Pillow import every one of its ~45
    # format plugins to look up ".png", ~40 ms of a 0.35 s command.
    from PIL import Image
    from PIL.PngImagePlugin import PngInfo

    info = PngInfo()
    for key, value in metadata.items():
        info.add_text(key, value)
    Image.fromarray(encode_srgb8(image)).save(f, format="PNG", pnginfo=info, compress_level=PNG_COMPRESS_LEVEL)


def _write_exr(path, image, metadata) -> None:
    import OpenEXR

    height, width, rows = _row_source(image)
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    header.update(metadata)  # the same keys as the PNG text chunks
    channels = {"RGB": np.ascontiguousarray(rows(0, height), dtype=np.float32)}
    try:
        with OpenEXR.File(header, channels) as exr:
            try:
                path.encode()
            except UnicodeEncodeError:  # a directory name that is not UTF-8: OpenEXR takes only text paths
                with open(path, "wb") as f:
                    exr.write(f)
            else:
                exr.write(path)
    except RuntimeError as e:  # OpenEXR's way of saying the disk is full or the file unwritable
        raise OSError(errno.EIO, str(e).splitlines()[0] if str(e) else "OpenEXR could not write the file") from None


def read_png_metadata(path: str) -> dict[str, str]:
    """Text chunks of a PNG (seed, scene, partial flag...); used by the tests."""
    from PIL import Image

    with Image.open(path) as im:
        return dict(im.text)
