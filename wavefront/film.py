"""The film (per-pixel sums and sample counts) and checkpoints of it.

Unit results are added in unit order (see :mod:`wavefront.units`), so "the
film after the first k units" is a complete description of a partial render:
a checkpoint is that film, ``k``, and a fingerprint of everything that
decides the image.
"""

from __future__ import annotations

import contextlib
import dataclasses
import hashlib
import os
import stat
import struct
import tempfile

import numpy as np

from .units import Unit, UnitPlan
from .validation import first_line

FLOAT32_MAX = float(np.finfo(np.float32).max)
# Bump when the unit plan or the film's meaning changes: a checkpoint made by
# another plan would resume into the wrong samples.
CHECKPOINT_VERSION = 3  # 3: the dropped samples are saved, and the name left out
FILM_BYTES_PER_PIXEL = 3 * 8 + 4  # float64 RGB sums + uint32 count


class Film:
    """Per-pixel sums and sample counts, filled in unit order."""

    def __init__(self, width: int, height: int, sums: np.ndarray | None = None, count: np.ndarray | None = None,
                 dropped: int = 0):
        """An empty film, or one holding ``sums (3, W*H)`` float64 and ``count (W*H,)`` uint32 (not copied)
        and ``dropped``, the non-finite samples its units left out (so its counts add up to the plan's)."""
        self.width, self.height = width, height
        self.dropped = dropped
        self.sum = np.zeros((3, width * height)) if sums is None else sums
        # uint32: 4 bytes a pixel instead of 8 (a 4K film is 33 MB less)
        self.count = np.zeros(width * height, dtype=np.uint32) if count is None else count

    def add(self, unit: Unit, total: np.ndarray, count: np.ndarray | int) -> None:
        """Add a unit's per-pixel sums ``total (3, P)`` and ``count (P,)``, or
        one count for every pixel (its tile, row-major)."""
        # the tile is a rectangle of the image: sliced views, not a gather and
        # scatter through pixel indices (half the time, in the parent, which
        # merges while the workers render); the same additions.  Splitting
        # the last axis is a view for any strides (a checkpoint's arrays may
        # be in Fortran order), so the adds land in the film.
        h, w = unit.y1 - unit.y0, unit.x1 - unit.x0
        tile = np.s_[unit.y0:unit.y1, unit.x0:unit.x1]
        self.sum.reshape(3, self.height, self.width)[(slice(None), *tile)] += total.reshape(3, h, w)
        counts = self.count.reshape(self.height, self.width)[tile]
        counts += np.uint32(count) if isinstance(count, int) else count.astype(np.uint32).reshape(h, w)

    def rows(self, y0: int, y1: int) -> np.ndarray:
        """Mean of each pixel's samples for image rows ``y0:y1``, (rows, W, 3) float32; 0 where none."""
        a, b = y0 * self.width, y1 * self.width
        c = self.count[a:b]
        with np.errstate(invalid="ignore", divide="ignore"):
            mean = np.where(c > 0, self.sum[:, a:b] / c, 0.0)
        # a finite float64 mean can exceed float32: clamp, never store inf
        return np.minimum(mean, FLOAT32_MAX).T.astype(np.float32).reshape(y1 - y0, self.width, 3)

    def image(self) -> np.ndarray:
        """Mean of each pixel's samples, (H, W, 3) float32; 0 where none."""
        out = np.empty((self.height, self.width, 3), dtype=np.float32)
        step = max(1, (1 << 20) // self.width)  # bounded temporaries
        for y0 in range(0, self.height, step):
            y1 = min(self.height, y0 + step)
            out[y0:y1] = self.rows(y0, y1)
        return out

    @property
    def pixels_without_samples(self) -> int:
        return int(self.count.size - np.count_nonzero(self.count))


# --- checkpoints ------------------------------------------------------------

class CheckpointError(ValueError):
    """A checkpoint file cannot be used to resume this render."""


def _feed(h, value) -> None:
    """Hash ``value``'s full content in a canonical, type-tagged form."""
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        h.update(b"D" + type(value).__qualname__.encode() + b"\0")
        for f in dataclasses.fields(value):
            if not f.metadata.get("fingerprint", True):  # metadata that never reaches the image
                continue
            h.update(f.name.encode() + b"=")
            _feed(h, getattr(value, f.name))
    elif isinstance(value, np.ndarray):
        a = np.ascontiguousarray(value)
        h.update(b"A" + a.dtype.str.encode() + repr(a.shape).encode())
        h.update(a.tobytes())
    elif isinstance(value, (bool, np.bool_)):
        h.update(b"B1" if value else b"B0")
    elif isinstance(value, (int, np.integer)):
        h.update(b"I" + str(int(value)).encode() + b"\0")
    elif isinstance(value, (float, np.floating)):
        h.update(b"F" + float(value).hex().encode() + b"\0")
    elif isinstance(value, str):
        # surrogatepass: a path with undecodable bytes (os.fsdecode's
        # surrogates) is hashed too; valid text hashes as plain UTF-8
        data = value.encode("utf-8", "surrogatepass")
        h.update(b"S" + struct.pack("<Q", len(data)) + data)
    elif value is None:
        h.update(b"N")
    elif isinstance(value, (list, tuple)):
        h.update(b"L" + struct.pack("<Q", len(value)))
        for item in value:
            _feed(h, item)
    elif isinstance(value, dict):
        h.update(b"M" + struct.pack("<Q", len(value)))
        for key in sorted(value, key=repr):
            _feed(h, key)
            _feed(h, value[key])
    else:
        raise TypeError(f"cannot fingerprint {type(value).__name__}")


def scene_fingerprint(scene) -> str:
    """SHA-256 of everything that decides the image: the scene's whole
    canonical content (every field, every array element, floats exactly),
    image size, samples, seed, and the checkpoint format's version.  Not its
    ``name`` (metadata, by default the file's name): a checkpoint resumes
    under a renamed or copied scene file."""
    h = hashlib.sha256(b"wavefront-checkpoint-%d\0" % CHECKPOINT_VERSION)
    _feed(h, scene)
    return h.hexdigest()


def save_checkpoint(path: str, scene, film: Film, units_done: int) -> None:
    """Write the film and the number of units merged so far, atomically.

    ``path`` must have passed :func:`wavefront.output.check_output_path`; the
    write goes through its symlink, if any, and never replaces anything but a
    regular file.
    """
    from .output import publish, resolve_target, temporary_prefix

    target = resolve_target(path)
    fd, tmp = tempfile.mkstemp(prefix=temporary_prefix("checkpoint"), suffix=".npz", dir=os.path.dirname(target))
    try:
        with os.fdopen(fd, "wb") as f:
            np.savez(f, fingerprint=scene_fingerprint(scene), units_done=np.int64(units_done),
                     dropped=np.int64(film.dropped), sum=film.sum, count=film.count)
        publish(tmp, target, path)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        raise


def _member_header(archive, name: str):
    """(shape, dtype) of an ``.npy`` member, read from its header alone, so a
    hostile file cannot make us allocate before it is checked."""
    with archive.open(name + ".npy") as f:
        version = np.lib.format.read_magic(f)
        if version == (1, 0):
            shape, fortran, dtype = np.lib.format.read_array_header_1_0(f)
        elif version == (2, 0):
            shape, fortran, dtype = np.lib.format.read_array_header_2_0(f)
        else:
            raise ValueError(f"unsupported .npy version {version}")
    return shape, dtype


def load_checkpoint(path: str, scene, units_total: int) -> tuple[Film, int]:
    """The film and units done of a checkpoint made by the same render.

    Raises
    ------
    CheckpointError
        If ``path`` is not a regular file, not a wavefront checkpoint, or one
        of another scene or settings.
    """
    try:
        mode = os.stat(path).st_mode
    except OSError as e:
        raise CheckpointError(f"{path}: cannot read: {e.strerror or e}") from None
    if not stat.S_ISREG(mode):
        raise CheckpointError(f"{path}: not a regular file")
    import zipfile  # only resuming needs it (np.savez imports it itself when saving)
    import zlib

    expected = {"fingerprint": None, "units_done": ((), np.dtype(np.int64)), "dropped": ((), np.dtype(np.int64)),
                "sum": ((3, scene.width * scene.height), np.dtype(np.float64)),
                "count": ((scene.width * scene.height,), np.dtype(np.uint32))}
    try:
        with zipfile.ZipFile(path) as archive:
            names = {n[:-4] for n in archive.namelist() if n.endswith(".npy")}
            if names != set(expected):
                raise ValueError(f"holds {', '.join(sorted(names)) or 'nothing'}")
            fp_shape, fp_dtype = _member_header(archive, "fingerprint")
            if fp_shape != () or fp_dtype.kind != "U" or fp_dtype.itemsize > 4 * 128:
                raise ValueError("bad fingerprint")
            with archive.open("fingerprint.npy") as f:
                fingerprint = str(np.lib.format.read_array(f, allow_pickle=False))
            if fingerprint != scene_fingerprint(scene):
                raise CheckpointError(f"{path}: made by a different scene or different settings "
                                      "(or an older wavefront); resume with the same scene file and flags")
            for name in ("units_done", "dropped", "sum", "count"):
                if _member_header(archive, name) != expected[name]:
                    raise ValueError(f"{name} has the wrong shape or type")
            arrays = {}
            for name in ("units_done", "dropped", "sum", "count"):
                with archive.open(name + ".npy") as f:
                    arrays[name] = np.lib.format.read_array(f, allow_pickle=False)
    except CheckpointError:
        raise
    # zipfile reports a damaged or unusual archive with many types: zlib.error
    # for a corrupt deflate stream, NotImplementedError for an unknown
    # compression method, RuntimeError for an encrypted member
    except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile, zipfile.LargeZipFile, zlib.error,
            NotImplementedError, RuntimeError) as e:
        raise CheckpointError(f"{path}: not a wavefront checkpoint ({first_line(e)})") from None
    units_done = int(arrays["units_done"])
    if not 0 <= units_done <= units_total:
        raise CheckpointError(f"{path}: not a wavefront checkpoint (units_done {units_done} out of range)")
    # a film's sums are of radiance (finite, never negative) and no pixel has
    # more samples than the render gives it: anything else would reach the image
    if not (np.isfinite(arrays["sum"]).all() and (arrays["sum"] >= 0.0).all()):
        raise CheckpointError(f"{path}: not a wavefront checkpoint (its pixel sums are not all finite and >= 0)")
    if arrays["count"].size and int(arrays["count"].max()) > scene.render.samples_per_pixel:
        raise CheckpointError(f"{path}: not a wavefront checkpoint (a pixel has more samples than "
                              f"{scene.render.samples_per_pixel} per pixel)")
    # ... nor more than the units done give it (a pixel may have fewer: non-finite samples are
    # dropped, and the checkpoint says how many: the counts must add up), and a pixel without
    # samples has nothing in its sums
    count = arrays["count"].reshape(scene.height, scene.width)
    plan = UnitPlan(scene.width, scene.height, scene.render.samples_per_pixel)
    if any((count[rows, columns] > samples).any() for rows, columns, samples in plan.samples_by_region(units_done)):
        raise CheckpointError(f"{path}: not a wavefront checkpoint (a pixel has more samples than the "
                              f"{units_done} units it has done give it)")
    dropped = int(arrays["dropped"])
    if dropped != plan.samples_before(units_done) - int(arrays["count"].sum(dtype=np.int64)):
        raise CheckpointError(f"{path}: not a wavefront checkpoint (its pixels' samples and the {dropped:,} "
                              f"it dropped do not add up to what its {units_done} units give)")
    if ((arrays["count"] == 0) & (arrays["sum"] != 0.0).any(axis=0)).any():
        raise CheckpointError(f"{path}: not a wavefront checkpoint (a pixel without samples has a non-zero sum)")
    return Film(scene.width, scene.height, arrays["sum"], arrays["count"], dropped), units_done  # no second copy
