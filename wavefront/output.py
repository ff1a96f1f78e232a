"""Writing images: PNG (8-bit sRGB), EXR (linear half/float), NPY (linear float32).

All writers go through a temporary file in the destination directory that is
renamed over the target only when complete, so a failed or interrupted write
never leaves a half-written or clobbered image.  :func:`check_output_path`
runs before rendering so a bad destination is reported in a second, not after
an hour of rendering.
"""

from __future__ import annotations

import os
import tempfile
import warnings

import numpy as np

FORMATS = (".png", ".exr", ".npy")
ENCODE_ROWS = 256  # sRGB-encode PNGs in strips of rows to bound peak memory


class OutputError(ValueError):
    """The output path cannot be written."""


def output_format(path: str) -> str:
    ext = os.path.splitext(path)[1].lower()
    if ext not in FORMATS:
        raise OutputError(f"{path}: unknown output extension {ext or '(none)'!r} "
                          f"(expected one of: {', '.join(FORMATS)})")
    return ext


def check_output_path(path: str) -> None:
    """Fail early if ``path`` has an unknown extension or cannot be written.

    The directory is probed by creating and removing a temporary file there,
    the same way the image will be written: permission bits alone do not
    tell (root passes ``os.access`` on read-only mounts and in ``/proc``).
    """
    output_format(path)
    directory = os.path.dirname(os.path.abspath(path)) or "."
    if not os.path.isdir(directory):
        raise OutputError(f"{path}: directory {directory} does not exist")
    if os.path.isdir(path):
        raise OutputError(f"{path}: is a directory")
    if os.path.exists(path) and not os.access(path, os.W_OK):
        raise OutputError(f"{path}: file is not writable")
    try:
        fd, probe = tempfile.mkstemp(prefix=".wavefront-probe-", dir=directory)
    except OSError as e:
        raise OutputError(f"{path}: cannot write in {directory} ({e.strerror or e})") from None
    os.close(fd)
    os.unlink(probe)


def encode_srgb8(image: np.ndarray) -> np.ndarray:
    """Linear RGB (H, W, 3) -> 8-bit sRGB with colour-science's transfer function.

    Values are clamped to [0, 1] before encoding (no tone mapping), as in the
    books, and rounded to nearest.
    """
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # colour warns that matplotlib is absent
        import colour
    out = np.empty(image.shape, dtype=np.uint8)
    for r0 in range(0, image.shape[0], ENCODE_ROWS):
        strip = np.clip(np.nan_to_num(image[r0:r0 + ENCODE_ROWS].astype(np.float64), nan=0.0), 0.0, 1.0)
        encoded = colour.cctf_encoding(strip, function="sRGB")
        out[r0:r0 + ENCODE_ROWS] = np.clip(np.rint(encoded * 255.0), 0, 255).astype(np.uint8)
    return out


def write_image(path: str, image: np.ndarray, metadata: dict[str, str] | None = None) -> None:
    """Write a linear float image of shape (H, W, 3) atomically.

    ``metadata`` goes into PNG text chunks and EXR header attributes.
    """
    ext = output_format(path)
    metadata = {k: str(v) for k, v in (metadata or {}).items()}
    directory = os.path.dirname(os.path.abspath(path))
    fd, tmp = tempfile.mkstemp(prefix=".wavefront-", suffix=ext, dir=directory)
    try:
        with os.fdopen(fd, "wb") as f:
            if ext == ".npy":
                np.save(f, np.ascontiguousarray(image, dtype=np.float32))
            elif ext == ".png":
                _write_png(f, image, metadata)
        if ext == ".exr":
            _write_exr(tmp, image, metadata)
        publish(tmp, path)
    except BaseException:
        try:
            os.unlink(tmp)
        except FileNotFoundError:
            pass
        raise


def publish(tmp: str, path: str) -> None:
    """Give a finished temporary file normal permissions and move it into place."""
    os.chmod(tmp, 0o666 & ~_umask())
    os.replace(tmp, path)


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def _write_png(f, image, metadata) -> None:
    import imageio.v3 as iio
    from PIL.PngImagePlugin import PngInfo

    info = PngInfo()
    for key, value in metadata.items():
        info.add_text(key, value)
    iio.imwrite(f, encode_srgb8(image), extension=".png", pnginfo=info)


def _write_exr(path, image, metadata) -> None:
    import OpenEXR

    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    header.update(metadata)  # the same keys as the PNG text chunks
    channels = {"RGB": np.ascontiguousarray(image, dtype=np.float32)}
    with OpenEXR.File(header, channels) as exr:
        exr.write(path)


def read_png_metadata(path: str) -> dict[str, str]:
    """Text chunks of a PNG (seed, scene, partial flag...); used by the tests."""
    from PIL import Image

    with Image.open(path) as im:
        return dict(im.text)
