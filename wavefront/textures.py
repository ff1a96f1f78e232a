"""Textures: colours that vary over a surface (RTOW book 2, "Texture Mapping" and "Perlin Noise").

Any colour parameter of a material (``albedo`` of lambertian and metal,
``color`` of emissive) is either an RGB triple or one of these:

=======================================  =====================================================
texture                                  value at a hit
=======================================  =====================================================
:class:`Checker` ``{type: checker}``     RTOW's solid (3D) checker: ``even`` where
                                         ``floor(x/scale) + floor(y/scale) + floor(z/scale)``
                                         is even at the world-space hit point, else ``odd``
:class:`ImageTexture` ``{type: image}``  a picture looked up at the shape's ``uv``
:class:`Noise` ``{type: noise}``         RTOW's Perlin marble,
                                         ``0.5 (1 + sin(scale z + 10 turbulence(p, 7)))``
=======================================  =====================================================

``even`` and ``odd`` are colours or textures in turn.  Every texture checks
its values when it is built, as the other scene objects do.

When a scene is compiled, its textures become one :class:`TextureTable`;
:meth:`TextureTable.evaluate` answers a whole batch of hits at once (one
NumPy pass per checker nesting level, per image and per noise texture; never
a loop over hits).  Materials, emitters and (later) media read their colours
through it.  A new colour parameter needs three steps: check it with
:func:`texture_field` in its object's ``__post_init__`` (errors then name
``albedo.odd.scale``), register it at compile time with ``node =
table.add(value)`` (``table.mean(node)`` is its average colour), and call
``table.evaluate(node_per_row, point, uv)`` on the rows that need it.  A
volume has no ``uv``: pass ``None``, which only image textures refuse.
"""

from __future__ import annotations

import contextlib
import contextvars
import os
import sys
import warnings
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import ClassVar

import numpy as np

from .validation import (MAX_COLOR, SceneError, color, describe, fail, first_line, integer, join, number, source_of,
                         string)

RGB = tuple[float, float, float]

# The largest image a texture may hold: 16 M pixels (4096 x 4096), 192 MiB as
# linear float32 RGB.  Checked from the file's header before it is decoded, so
# a hostile file cannot make the loader allocate first.
MAX_TEXTURE_PIXELS = 1 << 24
FILTERS = ("bilinear", "nearest")
# What an image does past its edges, per axis: ``clamp`` (RTOW: the edge
# texel goes on) or ``repeat`` (pbrt's and Mitsuba's default: the picture
# tiles).  A globe wants ``[repeat, clamp]``: its ``u`` wraps around at the
# seam, where a clamped bilinear filter shows a half-texel line, and its
# ``v`` must not blend one pole with the other.
WRAPS = ("clamp", "repeat")
# RTOW's Perlin noise: 256 lattice vectors, and turbulence summed over 7 octaves.
PERLIN_POINTS = 256
TURBULENCE_DEPTH = 7
# Seeds go to numpy's SeedSequence, which takes any non-negative integer; the
# bound keeps them what the scene's own seed may be.
MAX_TEXTURE_SEED = 2**63 - 1
# Checkers nested deeper than this are refused: each level is one pass over the hits.
MAX_NESTING = 16


@dataclass(frozen=True)
class Checker:
    """RTOW's ``checker_texture`` (the solid one).

    ==========  ==========  ===================================================
    parameter   default     meaning
    ==========  ==========  ===================================================
    ``scale``   1           edge of one cube of the pattern, world units (> 0)
    ``even``    (0,0,0)     colour or texture where the cube's index sum is even
    ``odd``     (1,1,1)     colour or texture where it is odd
    ==========  ==========  ===================================================
    """

    scale: float = 1.0
    even: RGB | Texture = (0.0, 0.0, 0.0)
    odd: RGB | Texture = (1.0, 1.0, 1.0)
    type: ClassVar[str] = "checker"

    def __post_init__(self):
        object.__setattr__(self, "scale", number(self, self.scale, "scale", low=0.0, low_open=True))
        for key in ("even", "odd"):
            object.__setattr__(self, key, texture_field(self, getattr(self, key), key))
        if nesting(self) > MAX_NESTING:
            fail(self, "", f"checkers nested more than {MAX_NESTING} deep")


@dataclass(frozen=True)
class ImageTexture:
    """RTOW's ``image_texture``: a picture wrapped on the shape by its ``uv``.

    ==========  ==========  ===================================================
    parameter   default     meaning
    ==========  ==========  ===================================================
    ``file``    required    PNG, JPEG, ... (8 or 16 bits per channel: sRGB,
                            decoded to linear with colour-science) or EXR /
                            floating-point TIFF (linear); a scene file's path
                            is relative to the scene file
    ``filter``  bilinear    ``bilinear`` (between the four nearest texel
                            centres) or ``nearest`` (RTOW's lookup)
    ``wrap``    clamp       past the edges: ``clamp`` (RTOW) or ``repeat``,
                            for both axes, or ``[u, v]`` each its own (a
                            globe: ``[repeat, clamp]``)
    ==========  ==========  ===================================================

    ``u`` runs left to right, ``v`` bottom to top (``v = 0`` is the bottom
    row, as in RTOW).
    Grey images are grey, an alpha channel is ignored.  At most
    ``MAX_TEXTURE_PIXELS`` pixels.  ``pixels`` may be given instead of a
    file from Python: linear RGB, shape ``(height, width, 3)``.
    """

    # where the pixels came from: not part of the checkpoint fingerprint, which hashes the pixels
    # themselves (a scene run from another directory names the same picture by another path)
    file: str | None = field(default=None, metadata={"fingerprint": False})
    filter: str = "bilinear"
    pixels: np.ndarray | None = field(default=None, compare=False, repr=False)
    wrap: str | tuple[str, str] = "clamp"
    type: ClassVar[str] = "image"

    def __post_init__(self):
        object.__setattr__(self, "filter", string(self, self.filter, "filter", FILTERS))
        object.__setattr__(self, "wrap", wrap_field(self, self.wrap))
        if self.pixels is None:
            if self.file is None:
                fail(self, "file", "required key is missing")
            file = os.fspath(self.file) if isinstance(self.file, os.PathLike) else self.file
            object.__setattr__(self, "file", string(self, file, "file"))
            object.__setattr__(self, "pixels", read_image(self, self.file))
        else:
            if self.file is not None:  # which picture would be meant is anyone's guess
                fail(self, "file", "give file or pixels, not both")
            object.__setattr__(self, "pixels", image_pixels(self, self.pixels))

    def lookup(self, uv: np.ndarray) -> np.ndarray:
        """Linear RGB ``(3, N)`` at ``uv (2, N)``."""
        return lookup(self.pixels, uv, self.filter, self.wrap)


def wrap_field(obj, value) -> tuple[str, str]:
    """``wrap`` as ``(u, v)``: one of :data:`WRAPS` for both axes, or a list of two."""
    if isinstance(value, str):
        value = string(obj, value, "wrap", WRAPS)
        return value, value
    if not isinstance(value, (list, tuple)) or len(value) != 2:
        fail(obj, "wrap", f"expected one of: {', '.join(WRAPS)}, or a list of two of them ([u, v]), got {describe(value)}")
    return tuple(string(obj, w, join("wrap", i), WRAPS) for i, w in enumerate(value))


@dataclass(frozen=True)
class Noise:
    """RTOW's ``noise_texture``: grey marble from Perlin turbulence.

    ==========  ==========  ===================================================
    parameter   default     meaning
    ==========  ==========  ===================================================
    ``scale``   1           frequency of the marble's stripes along z (> 0)
    ``seed``    0           seeds the noise's own lattice (never the render's
                            seed: ``--seed`` changes the estimate's noise, not
                            the marble)
    ==========  ==========  ===================================================
    """

    scale: float = 1.0
    seed: int = 0
    type: ClassVar[str] = "noise"

    def __post_init__(self):
        object.__setattr__(self, "scale", number(self, self.scale, "scale", low=0.0, low_open=True))
        object.__setattr__(self, "seed", integer(self, self.seed, "seed", low=0, high=MAX_TEXTURE_SEED))


Texture = Checker | ImageTexture | Noise
TEXTURE_TYPES = {cls.type: cls for cls in (Checker, ImageTexture, Noise)}


def nesting(value) -> int:
    """How many checkers deep ``value`` goes (0 for a colour or a leaf texture)."""
    if isinstance(value, Checker):
        return 1 + max(nesting(value.even), nesting(value.odd))
    return 0


def is_texture(value) -> bool:
    return isinstance(value, (Checker, ImageTexture, Noise))


def texture_field(obj, value, path: str):
    """A colour parameter: an RGB triple (returned as a tuple of floats), a
    texture object, or a scene file's mapping ``{type: checker | image | noise, ...}``."""
    if is_texture(value):
        return value
    if isinstance(value, Mapping):
        return texture_from_dict(obj, value, path)
    return color(obj, value, path)


def texture_from_dict(obj, spec: Mapping, path: str):
    """A texture from its mapping; errors name ``path.key`` under ``obj``'s source."""
    for key in spec:
        if not isinstance(key, str):
            fail(obj, path, f"keys must be strings, got {describe(key)}")
    if "type" not in spec:
        fail(obj, join(path, "type"), f"required key is missing (expected one of: {', '.join(TEXTURE_TYPES)})")
    kind = string(obj, spec["type"], join(path, "type"), tuple(TEXTURE_TYPES))
    cls = TEXTURE_TYPES[kind]
    allowed = {"scale", "even", "odd"} if cls is Checker else {"file", "filter", "wrap"} if cls is ImageTexture \
        else {"scale", "seed"}
    for key in spec:
        if key != "type" and key not in allowed:
            fail(obj, join(path, key), f"unknown key (expected one of: {', '.join(sorted(allowed | {'type'}))})")
    if cls is ImageTexture and "file" not in spec:
        fail(obj, join(path, "file"), "required key is missing")
    try:
        return cls(**{k: v for k, v in spec.items() if k != "type"})
    except SceneError as e:
        raise SceneError(source_of(obj), join(path, e.path), e.problem) from None


# -- images ------------------------------------------------------------------

def _too_big(obj, width: int, height: int, file: str | None = None) -> None:
    if width * height > MAX_TEXTURE_PIXELS:
        where = f"{file}: " if file else ""
        fail(obj, "file", f"{where}the image is {width}x{height} = {width * height} pixels; the limit is "
                          f"{MAX_TEXTURE_PIXELS} ({MAX_TEXTURE_PIXELS * 12 >> 20} MiB as linear float RGB)")


# What loading an image holds at its peak, per pixel: the decoded 8-bit (or
# 16-bit) pixels, the float32 RGB result and a grey image's widened copy.
IMAGE_LOAD_BYTES_PER_PIXEL = 24


def image_header(obj, file: str) -> tuple[str, int, int, int]:
    """``(format, width, height, images)`` of ``file`` from its header alone
    (``format`` is ``exr`` or ``imageio``); a SceneError at ``file`` if it is
    missing, not a regular file, unreadable, not an image, or too big."""
    if not os.path.isfile(file):
        fail(obj, "file", f"{file}: no such file" if not os.path.exists(file) else f"{file}: not a regular file")
    try:
        with open(file, "rb") as f:
            magic = f.read(4)
    except OSError as e:
        fail(obj, "file", f"{file}: cannot read ({e.strerror or e})")
    if magic == b"\x76\x2f\x31\x01":  # OpenEXR's magic number
        import OpenEXR

        try:
            with _silenced_output(), OpenEXR.File(file, header_only=True) as exr:
                (x0, y0), (x1, y1) = exr.header()["dataWindow"]
        except Exception as e:  # OpenEXR raises RuntimeError and others on a damaged header
            fail(obj, "file", f"{file}: cannot read as OpenEXR ({first_line(e)})")
        width, height, images = int(x1 - x0 + 1), int(y1 - y0 + 1), 1
        kind = "exr"
    else:
        import imageio.v3 as iio

        try:
            with _without_pillows_size_limit():
                props = iio.improps(file)
        except Exception as e:  # imageio's plugins raise many kinds; any of them means "not an image we read"
            fail(obj, "file", f"{file}: not an image imageio can read ({first_line(e)})")
        shape, images = props.shape, props.n_images or 1
        if len(shape) > 3:  # a stack of frames (pillow gives even one GIF frame as one)
            shape = shape[1:]
        if len(shape) < 2:
            fail(obj, "file", f"{file}: not a 2D image (shape {shape})")
        width, height, kind = int(shape[1]), int(shape[0]), "imageio"
    _too_big(obj, width, height, file)
    return kind, width, height, images


@contextlib.contextmanager
def _without_pillows_size_limit():
    """Pillow's decompression-bomb check off while only a header is read:
    past 89 M pixels it warned, past 179 M it raised, each in its own words;
    wavefront's own limit (``MAX_TEXTURE_PIXELS``, far lower) follows from
    the header's size, with its own message, before anything is decoded."""
    try:
        from PIL import Image
    except ImportError:  # pragma: no cover - imageio reads with other plugins then
        yield
        return
    saved = Image.MAX_IMAGE_PIXELS
    Image.MAX_IMAGE_PIXELS = None
    try:
        yield
    finally:
        Image.MAX_IMAGE_PIXELS = saved


def image_load_bytes(file: str) -> int | None:
    """About how much memory loading ``file`` takes (None if its header does
    not say: the texture's own checks then report the problem)."""
    try:
        _, width, height, _ = image_header(None, file)
    except SceneError:
        return None
    return width * height * IMAGE_LOAD_BYTES_PER_PIXEL


_SHARED: contextvars.ContextVar[dict | None] = contextvars.ContextVar("wavefront_shared_images", default=None)


@contextlib.contextmanager
def images_shared():
    """Within it, an image file that several textures name is decoded once
    and its pixels shared (read-only): one 1024x1024 picture on 12 materials
    was decoded 12 times (~160 MiB), and a budget that held it once refused
    the scene.  Scoped to one scene load, so nothing outlives it."""
    token = _SHARED.set({})
    try:
        yield
    finally:
        _SHARED.reset(token)


def read_image(obj, file: str) -> np.ndarray:
    """The image ``file`` as linear float32 RGB ``(height, width, 3)``.

    The size is read from the header first and refused above
    ``MAX_TEXTURE_PIXELS`` before any pixel is decoded.  Inside
    :func:`images_shared` one file is decoded once (by its real path, size and
    modification time)."""
    shared = _SHARED.get()
    key = None
    if shared is not None:
        with contextlib.suppress(OSError):
            info = os.stat(file)
            key = (os.path.realpath(file), info.st_size, info.st_mtime_ns)
        if key in shared:
            return shared[key]
    pixels = _decode_image(obj, file)
    if key is not None:
        pixels.flags.writeable = False  # shared by every texture naming the file
        shared[key] = pixels
    return pixels


def _decode_image(obj, file: str) -> np.ndarray:
    kind, _, _, _ = image_header(obj, file)
    if kind == "exr":
        return _read_exr(obj, file)
    import imageio.v3 as iio

    try:
        # index 0: the first frame of an animation or stack; without it pillow
        # returns even a one-frame GIF as a stack of shape (1, H, W, 3)
        options = {"index": 0}
        if iio.immeta(file, index=0).get("mode") == "CMYK":  # printers' ink (a CMYK JPEG), not red-green-blue-alpha
            options["mode"] = "RGB"
        data = iio.imread(file, **options)
    except Exception as e:
        fail(obj, "file", f"{file}: cannot decode ({first_line(e)})")
    return image_pixels(obj, data, path="file", size_checked=True, file=file)


@contextlib.contextmanager
def _silenced_output():
    """File descriptors 1 and 2 to /dev/null meanwhile: OpenEXR's C++ core
    prints a damaged file's problems there itself (two extra lines besides
    the exception that becomes our one-line error)."""
    for stream in (sys.stdout, sys.stderr):
        if stream is not None:
            stream.flush()
    try:
        saved = [os.dup(1), os.dup(2)]
        null = os.open(os.devnull, os.O_WRONLY)
    except OSError:  # a descriptor is closed: nothing to silence
        yield
        return
    try:
        os.dup2(null, 1)
        os.dup2(null, 2)
        yield
    finally:
        os.dup2(saved[0], 1)
        os.dup2(saved[1], 2)
        for fd in (*saved, null):
            os.close(fd)


def _read_exr(obj, file: str) -> np.ndarray:
    import OpenEXR

    try:
        with _silenced_output(), OpenEXR.File(file, separate_channels=True) as exr:
            # copied out: closing the file empties the channel dictionary
            channels = {name: np.array(c.pixels) for name, c in exr.channels().items()}
    except SceneError:
        raise
    except Exception as e:
        fail(obj, "file", f"{file}: cannot read as OpenEXR ({first_line(e)})")
    names = {name.split(".")[-1]: name for name in channels}
    if {"R", "G", "B"} <= names.keys():
        data = np.stack([channels[names[c]] for c in "RGB"], axis=-1)
    elif "Y" in names:
        data = channels[names["Y"]]
    else:
        fail(obj, "file", f"{file}: no R, G, B or Y channels (has {', '.join(sorted(channels))})")
    return image_pixels(obj, np.asarray(data, dtype=np.float32), path="file", size_checked=True, file=file)


def image_pixels(obj, data, path: str = "pixels", size_checked: bool = False, file: str | None = None) -> np.ndarray:
    """An image array as linear float32 RGB ``(height, width, 3)``.

    Integer images (8 or 16 bits) are sRGB-encoded: decoded with
    colour-science's sRGB ``cctf_decoding``, through a lookup table of every
    code value (exactly colour's numbers, at a table lookup's cost).  Float
    images are linear already, and held to the limits of a literal colour:
    finite, >= 0 and at most ``MAX_COLOR``.  ``file`` (the image's) is named
    in the messages."""
    where = f"{file}: " if file else ""
    a = np.asarray(data)
    if a.ndim == 2:
        a = a[:, :, None]
    if a.ndim != 3 or a.shape[0] == 0 or a.shape[1] == 0 or a.shape[2] not in (1, 2, 3, 4):
        fail(obj, path, f"expected an image of shape (height, width, 1-4 channels), got shape {a.shape}")
    if not size_checked:  # a file's size was checked from its header
        _too_big(obj, a.shape[1], a.shape[0])
    if a.shape[2] in (1, 2):  # grey, or grey and alpha
        a = np.repeat(a[:, :, :1], 3, axis=2)
    a = a[:, :, :3]
    if a.dtype.kind == "b":  # a 1-bit image: black and white are the same in sRGB and linear
        a = a.astype(np.uint8) * np.uint8(255)
    if a.dtype.kind in "ui":
        levels = np.iinfo(a.dtype).max
        if a.dtype.kind == "i" or levels > 65535:
            fail(obj, path, f"unsupported pixel type {a.dtype} (8- or 16-bit unsigned, or float)")
        return np.ascontiguousarray(srgb_decoding(levels)[a])
    if a.dtype.kind != "f":
        fail(obj, path, f"unsupported pixel type {a.dtype}")
    out = np.ascontiguousarray(a, dtype=np.float32)
    if not np.isfinite(out).all():
        fail(obj, path, f"{where}the image holds NaN or infinite values")
    if (out < 0).any():
        fail(obj, path, f"{where}the image holds negative values (a colour is >= 0)")
    if out.size and out.max() > MAX_COLOR:  # as a literal colour: beyond it a render's float32 overflows
        fail(obj, path, f"{where}the image holds values up to {float(out.max()):g}; a colour is at most {MAX_COLOR:g}")
    return out


# colour-science's sRGB decoding of the 256 8-bit codes, made and checked by
# data/make_srgb8_decoding.py: an 8-bit texture (the common kind) is decoded
# without importing colour-science (~0.5 s); 16-bit ones import it.
SRGB8_DECODING = os.path.join(os.path.dirname(os.path.abspath(__file__)), "data", "srgb8_decoding.txt")


def srgb_decoding(levels: int) -> np.ndarray:
    """(levels + 1,) float32: colour-science's linear value of every code of an
    image with ``levels + 1`` sRGB codes (255: 8-bit, 65535: 16-bit)."""
    if levels == 255:
        with open(SRGB8_DECODING) as f:
            table = np.array([float.fromhex(line) for line in f if line.strip() and not line.startswith("#")],
                             dtype=np.float32)
        if table.shape != (256,) or not np.all(np.diff(table) > 0):  # a damaged install, not a user's input
            raise RuntimeError(f"{SRGB8_DECODING}: not 256 increasing values")
        return table
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # colour warns that matplotlib is absent
        import colour
    return np.asarray(colour.cctf_decoding(np.arange(levels + 1) / levels, function="sRGB"), dtype=np.float32)


def lookup(pixels: np.ndarray, uv: np.ndarray, filter: str, wrap=("clamp", "clamp")) -> np.ndarray:
    """Linear RGB ``(3, N)`` of ``pixels (H, W, 3)`` at ``uv (2, N)``.

    ``nearest`` is RTOW's ``image_texture::value``: ``i = int(u W)``,
    ``j = int((1 - v) H)``.  ``bilinear`` blends the four texel centres
    around ``(u W - 1/2, (1 - v) H - 1/2)``.  ``wrap (u, v)`` says per axis
    what lies past the edges (:data:`WRAPS`): texel indices are clamped, or
    taken modulo the size (after the floor, so a coordinate of any size
    wraps exactly)."""
    height, width = pixels.shape[:2]
    u = np.asarray(uv[0], dtype=np.float64)
    v = 1.0 - np.asarray(uv[1], dtype=np.float64)  # flip: row 0 is the top
    # clamped axes clamp the coordinate too (RTOW): u = 1 is the last texel, not one past it
    if wrap[0] == "clamp":
        u = np.clip(u, 0.0, 1.0)
    if wrap[1] == "clamp":
        v = np.clip(v, 0.0, 1.0)

    def index(k, size, mode):
        return np.clip(k, 0, size - 1) if mode == "clamp" else np.mod(k, size)

    if filter == "nearest":
        i = index(np.floor(u * width).astype(np.int64), width, wrap[0])
        j = index(np.floor(v * height).astype(np.int64), height, wrap[1])
        return pixels[j, i].T.astype(np.float64)
    x = u * width - 0.5
    y = v * height - 0.5
    x0, y0 = np.floor(x), np.floor(y)
    fx, fy = x - x0, y - y0
    i0 = index(x0.astype(np.int64), width, wrap[0])
    i1 = index(x0.astype(np.int64) + 1, width, wrap[0])
    j0 = index(y0.astype(np.int64), height, wrap[1])
    j1 = index(y0.astype(np.int64) + 1, height, wrap[1])
    flat = pixels.reshape(-1, 3)
    top = flat[j0 * width + i0].T * (1.0 - fx) + flat[j0 * width + i1].T * fx
    bottom = flat[j1 * width + i0].T * (1.0 - fx) + flat[j1 * width + i1].T * fx
    return top * (1.0 - fy) + bottom * fy


# -- Perlin noise ------------------------------------------------------------

@dataclass(frozen=True)
class Perlin:
    """RTOW's ``perlin`` class: random unit vectors on a lattice hashed by three
    permutation tables, interpolated with Hermite smoothing (book 2, 5.6-5.8)."""

    random_vector: np.ndarray  # (3, PERLIN_POINTS) unit
    permutation: np.ndarray  # (3, PERLIN_POINTS) int: perm_x, perm_y, perm_z

    @classmethod
    def build(cls, seed: int) -> Perlin:
        """The tables from the texture's own seed: as the book's constructor,
        with ``np.random.default_rng(seed)`` for its ``random_double``."""
        rng = np.random.default_rng(seed)
        vectors = rng.uniform(-1.0, 1.0, size=(3, PERLIN_POINTS))
        vectors /= np.linalg.norm(vectors, axis=0)
        permutation = np.stack([rng.permutation(PERLIN_POINTS) for _ in range(3)])
        return cls(vectors, permutation)

    def noise(self, p: np.ndarray) -> np.ndarray:
        """Noise in about [-1, 1] at points ``p (3, N)``; shape ``(N,)``.

        The book's ``perlin::noise`` and ``perlin_interp``: the lattice vectors
        at the cell's eight corners, each dotted with the offset from its
        corner, blended with Hermite weights.  The corners stay a loop of
        eight vectorised steps: gathering all eight as one ``(3, 2, 2, 2, N)``
        array measured 1.7x slower (memory traffic, not Python, dominates);
        blending one axis at a time takes half the arithmetic of the book's
        sum of eight weighted terms (the same value, rounded differently)."""
        floor = np.floor(p)
        frac = p - floor
        # the lattice cell modulo the table (the book's "& 255" on int(floor)),
        # taken in floating point so that no coordinate overflows an integer
        cell = np.mod(floor, PERLIN_POINTS).astype(np.int64)
        mask = PERLIN_POINTS - 1
        gx, gy, gz = self.random_vector
        perm_x, perm_y, perm_z = self.permutation
        # per axis: the hash and the offset from the lower (0) and upper (1) corner
        hx = (perm_x.take(cell[0] & mask), perm_x.take((cell[0] + 1) & mask))
        hy = (perm_y.take(cell[1] & mask), perm_y.take((cell[1] + 1) & mask))
        hz = (perm_z.take(cell[2] & mask), perm_z.take((cell[2] + 1) & mask))
        ox, oy, oz = (frac[0], frac[0] - 1.0), (frac[1], frac[1] - 1.0), (frac[2], frac[2] - 1.0)
        s = frac * frac * (3.0 - 2.0 * frac)  # Hermite cubic
        # the book's weight (i uu + (1 - i)(1 - uu)) (j vv + ...) (k ww + ...) of
        # corner (i, j, k), applied as three nested linear blends: x, then y, then z
        along_z = []
        for k in (0, 1):
            along_y = []
            for j in (0, 1):
                hyz = hy[j] ^ hz[k]
                dots = []
                for i in (0, 1):
                    h = hx[i] ^ hyz
                    dots.append(gx.take(h) * ox[i] + gy.take(h) * oy[j] + gz.take(h) * oz[k])
                along_y.append(dots[0] + s[0] * (dots[1] - dots[0]))
            along_z.append(along_y[0] + s[1] * (along_y[1] - along_y[0]))
        return along_z[0] + s[2] * (along_z[1] - along_z[0])

    def turbulence(self, p: np.ndarray, depth: int = TURBULENCE_DEPTH) -> np.ndarray:
        """``|sum_i 2^-i noise(2^i p)|`` over ``depth`` octaves; shape ``(N,)``."""
        total = np.zeros(p.shape[1])
        weight = 1.0
        q = p.copy()
        for _ in range(depth):
            total += weight * self.noise(q)
            weight *= 0.5
            q *= 2.0
        return np.abs(total)

    def marble(self, p: np.ndarray, scale: float) -> np.ndarray:
        """RTOW's ``noise_texture::value``: ``0.5 (1 + sin(scale z + 10 turbulence(p, 7)))``, ``(N,)``."""
        return 0.5 * (1.0 + np.sin(scale * p[2] + 10.0 * self.turbulence(p, TURBULENCE_DEPTH)))


# -- the compiled table --------------------------------------------------------

CONSTANT, CHECKER, IMAGE, NOISE = 0, 1, 2, 3


class TextureTable:
    """Every colour of a scene that is textured, as nodes of one table.

    :meth:`add` returns a node id for a colour or texture (a checker's
    children become nodes too); :meth:`evaluate` maps ``(node id, point, uv)``
    per hit to linear RGB.  Built once when the scene is compiled.
    """

    def __init__(self):
        self.kind: list[int] = []
        self.color: list[np.ndarray] = []  # per node: the constant, or the texture's mean
        self.scale: list[float] = []
        self.children: list[tuple[int, int]] = []
        self.leaf: dict[int, ImageTexture | tuple[Perlin, float]] = {}
        self._frozen = None

    def __len__(self) -> int:
        return len(self.kind)

    def add(self, value) -> int:
        """The node id of ``value`` (an RGB triple or a texture)."""
        node = len(self.kind)
        self.kind.append(CONSTANT)
        self.scale.append(1.0)
        self.children.append((node, node))
        self.color.append(np.zeros(3))
        if isinstance(value, Checker):
            even, odd = self.add(value.even), self.add(value.odd)
            self.kind[node], self.scale[node], self.children[node] = CHECKER, value.scale, (even, odd)
            # a solid checker covers each colour half the time on average
            self.color[node] = 0.5 * (self.color[even] + self.color[odd])
        elif isinstance(value, ImageTexture):
            self.kind[node] = IMAGE
            self.leaf[node] = value
            self.color[node] = value.pixels.reshape(-1, 3).mean(axis=0, dtype=np.float64)
        elif isinstance(value, Noise):
            self.kind[node] = NOISE
            self.leaf[node] = (Perlin.build(value.seed), value.scale)
            self.color[node] = np.full(3, 0.5)  # E[0.5 (1 + sin(...))] over a stripe's phase
        else:
            self.color[node] = np.asarray(value, dtype=np.float64)
        self._frozen = None
        return node

    def _arrays(self):
        if self._frozen is None:
            self._frozen = (np.array(self.kind, dtype=np.int8), np.array(self.color, dtype=np.float64).T.reshape(3, -1),
                            np.array(self.scale), np.array(self.children, dtype=np.int64).reshape(-1, 2).T)
        return self._frozen

    def mean(self, node: int) -> np.ndarray:
        """A principled average colour of node ``node`` ``(3,)``: an image's
        mean pixel, a checker's mean of its two colours, the marble's 0.5
        (its expected value over the stripes' phase).  Light sampling chooses
        a textured emitter by this power."""
        return self.color[node]

    @property
    def needs_uv(self) -> bool:
        return IMAGE in self.kind

    def evaluate(self, node: np.ndarray, point: np.ndarray, uv: np.ndarray | None) -> np.ndarray:
        """Linear RGB ``(3, N)`` float64 of nodes ``node (N,)`` at world points
        ``point (3, N)`` with surface coordinates ``uv (2, N)`` (needed only by
        images)."""
        kind, color, scale, children = self._arrays()
        node = np.asarray(node, dtype=np.int64).copy()
        p = np.asarray(point, dtype=np.float64)
        out = np.empty((3, node.shape[0]))
        for _ in range(MAX_NESTING + 1):  # one pass per nesting level of checkers
            rows = np.flatnonzero(kind.take(node) == CHECKER)
            if rows.size == 0:
                break
            at = node.take(rows)
            with np.errstate(over="ignore", invalid="ignore"):  # a tiny scale far out: inf, NaN -> odd
                q = np.floor(p[:, rows] / scale.take(at))
                total = q[0] + q[1] + q[2]
                even = total - 2.0 * np.floor(0.5 * total) == 0.0
            node[rows] = np.where(even, children[0].take(at), children[1].take(at))
        k = kind.take(node)
        rows = np.flatnonzero(k == CONSTANT)
        out[:, rows] = color[:, node.take(rows)]
        for leaf, value in self.leaf.items():  # one pass per image or noise texture of the scene
            rows = np.flatnonzero(node == leaf)
            if rows.size == 0:
                continue
            if isinstance(value, ImageTexture):
                if uv is None:
                    raise ValueError("an image texture needs uv")
                out[:, rows] = value.lookup(np.asarray(uv, dtype=np.float64)[:, rows])
            else:
                perlin, s = value
                out[:, rows] = perlin.marble(p[:, rows], s)
        return out


def mean_color(value) -> np.ndarray:
    """The average colour of a colour parameter (see :meth:`TextureTable.mean`)."""
    table = TextureTable()
    return table.mean(table.add(value))

