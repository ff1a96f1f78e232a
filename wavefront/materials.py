"""Materials: their parameters, and one vectorised scatter kernel per kind.

A material answers the book's three questions at once for a whole batch of
hits: did the ray scatter (``absorbed`` is the negation), how much is it
attenuated, and where does it go next.  A kernel receives its uniforms ``u``
as an argument (shape ``(2, N)`` or ``(3, N)``), holds no state and branches
only with masks, so the integrator can route any subset of rows to it.

Kernel signature::

    attenuation (3, N), direction (3, N), absorbed (N,) = kernel(
        direction_in (3, N) unit, normal (3, N) unit against the ray,
        front_face (N,), <the material's parameters gathered per row>, u)

Outgoing directions are unit length so intersection can assume ``|d| = 1``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import ClassVar

import numpy as np

from .sampling import random_unit_vector
from .textures import Texture, TextureTable, is_texture, texture_field
from .validation import color, number, warn
from .vecmath import dot, gather, normalize, reflect, refract, scatter, schlick, true_rows

# A lambertian scatter direction n + random_unit_vector() vanishes when the
# random vector is nearly -n; below this squared length fall back to n (the
# book's near_zero() uses 1e-8 per component).
DEGENERATE_SQUARED_LENGTH = 1e-16
# Bounds far outside any real material (indices ~1-4, a Phong exponent of 1e4
# is already a mirror) that keep a render's float32 arithmetic finite: an
# index of 1e-300 or an exponent of 1e300 printed NumPy overflow warnings.
MIN_REFRACTION_INDEX = 1e-6
MAX_SHININESS = 1e6

RGB = tuple[float, float, float]


@dataclass(frozen=True)
class Lambertian:
    """Ideal diffuse reflector.

    ============  =========  =====================================
    parameter     default    meaning
    ============  =========  =====================================
    ``albedo``    (.5,.5,.5) fraction of light reflected, per channel
                             (an RGB triple or a texture)
    ============  =========  =====================================
    """

    albedo: RGB | Texture = (0.5, 0.5, 0.5)
    kind: ClassVar[str] = "lambertian"

    def __post_init__(self):
        object.__setattr__(self, "albedo", texture_field(self, self.albedo, "albedo"))


@dataclass(frozen=True)
class Metal:
    """Mirror with an albedo tint; ``fuzz`` in [0, 1] roughens it.

    ============  =========  =====================================
    parameter     default    meaning
    ============  =========  =====================================
    ``albedo``    (.8,.8,.8) tint of the reflection, per channel
                             (an RGB triple or a texture)
    ``fuzz``      0          radius of the ball the reflected
                             direction is jittered in; clamped to 1
    ============  =========  =====================================
    """

    albedo: RGB | Texture = (0.8, 0.8, 0.8)
    fuzz: float = 0.0
    kind: ClassVar[str] = "metal"

    def __post_init__(self):
        object.__setattr__(self, "albedo", texture_field(self, self.albedo, "albedo"))
        fuzz = number(self, self.fuzz, "fuzz", low=0.0)
        # The lesson clamps fuzz to at most 1: beyond that the jitter ball
        # contains the origin and the lobe is no longer centred on the mirror
        # direction.
        if fuzz > 1.0:
            warn(self, "fuzz", f"{self.fuzz!r} clamped to 1")
        object.__setattr__(self, "fuzz", min(fuzz, 1.0))


@dataclass(frozen=True)
class Dielectric:
    """Clear glass-like material: Snell refraction, TIR, Schlick Fresnel.

    ======================  =======  =========================================
    parameter               default  meaning
    ======================  =======  =========================================
    ``refraction_index``    1.5      index relative to the medium outside the
                                     sphere (use 1/1.5 for an air bubble
                                     inside glass)
    ======================  =======  =========================================
    """

    refraction_index: float = 1.5
    kind: ClassVar[str] = "dielectric"

    def __post_init__(self):
        object.__setattr__(self, "refraction_index",
                           number(self, self.refraction_index, "refraction_index", low=MIN_REFRACTION_INDEX,
                                  high=1.0 / MIN_REFRACTION_INDEX))


@dataclass(frozen=True)
class Emissive:
    """A light: adds ``color`` times the path throughput and ends the path.

    ===========  =======  ====================================
    parameter    default  meaning
    ===========  =======  ====================================
    ``color``    (1,1,1)  emitted radiance (may exceed 1); an RGB
                          triple or a texture
    ===========  =======  ====================================
    """

    color: RGB | Texture = (1.0, 1.0, 1.0)
    kind: ClassVar[str] = "emissive"

    def __post_init__(self):
        object.__setattr__(self, "color", texture_field(self, self.color, "color"))


@dataclass(frozen=True)
class Phong:
    """Whitted/Phong material for the ``whitted`` integrator.

    ================  ==========  ==========================================
    parameter         default     meaning
    ================  ==========  ==========================================
    ``ambient``       (0,0,0)     k_a, multiplies the scene's ambient light
    ``diffuse``       (.5,.5,.5)  k_d, Lambert term per point light
    ``specular``      (0,0,0)     k_s, Phong highlight per point light
    ``shininess``     32          Phong exponent (>= 0)
    ``reflectivity``  (0,0,0)     k_r, weight of the mirror-reflected colour
    ================  ==========  ==========================================

    The path integrator treats it as lambertian with albedo ``diffuse``.
    """

    ambient: RGB = (0.0, 0.0, 0.0)
    diffuse: RGB = (0.5, 0.5, 0.5)
    specular: RGB = (0.0, 0.0, 0.0)
    shininess: float = 32.0
    reflectivity: RGB = (0.0, 0.0, 0.0)
    kind: ClassVar[str] = "phong"

    def __post_init__(self):
        for key in ("ambient", "diffuse", "specular"):
            object.__setattr__(self, key, color(self, getattr(self, key), key))
        object.__setattr__(self, "shininess", number(self, self.shininess, "shininess", low=0.0, high=MAX_SHININESS))
        object.__setattr__(self, "reflectivity", color(self, self.reflectivity, "reflectivity", high=1.0))


Material = Lambertian | Metal | Dielectric | Emissive | Phong
KINDS = tuple(cls.kind for cls in (Lambertian, Metal, Dielectric, Emissive, Phong))  # kind code = position


@dataclass(slots=True)
class MaterialTable:
    """The scene's materials as parallel arrays indexed by material id.

    Kernels gather their parameters with ``table.albedo[:, material_idx]``;
    a field a kind does not use holds a harmless placeholder.
    """

    kind: np.ndarray  # (K,) int8, index into KINDS
    albedo: np.ndarray  # (3, K) lambertian / metal / phong-diffuse
    fuzz: np.ndarray  # (K,)
    refraction_index: np.ndarray  # (K,)
    emission: np.ndarray  # (3, K)
    ambient: np.ndarray  # (3, K)
    specular: np.ndarray  # (3, K)
    shininess: np.ndarray  # (K,)
    reflectivity: np.ndarray  # (3, K)
    names: list[str] = field(default_factory=list)
    # Textured colours: the node of ``textures`` per material (-1: the plain
    # colour above).  Where textured, ``albedo`` / ``emission`` hold the
    # texture's mean (what light sampling's power and Whitted's metal use).
    albedo_texture: np.ndarray | None = None  # (K,) int32
    emission_texture: np.ndarray | None = None  # (K,) int32
    textures: TextureTable | None = None

    @classmethod
    def build(cls, materials: list[Material], names: list[str] | None = None, dtype=np.float64) -> MaterialTable:
        k = len(materials)
        t = cls(
            kind=np.array([KINDS.index(m.kind) for m in materials], dtype=np.int8),
            albedo=np.zeros((3, k)),
            fuzz=np.zeros(k),
            refraction_index=np.ones(k),
            emission=np.zeros((3, k)),
            ambient=np.zeros((3, k)),
            specular=np.zeros((3, k)),
            shininess=np.zeros(k),
            reflectivity=np.zeros((3, k)),
            names=list(names or [f"material{i}" for i in range(k)]),
        )
        textures = TextureTable()
        t.albedo_texture, t.emission_texture = np.full(k, -1, np.int32), np.full(k, -1, np.int32)

        def plain(value, i, ids):
            """The colour's RGB (a texture's mean), its texture node noted in ``ids``."""
            if not is_texture(value):
                return value
            ids[i] = textures.add(value)
            return textures.mean(ids[i])

        for i, m in enumerate(materials):
            if isinstance(m, (Lambertian, Metal)):
                t.albedo[:, i] = plain(m.albedo, i, t.albedo_texture)
            if isinstance(m, Metal):
                t.fuzz[i] = m.fuzz
                t.reflectivity[:, i] = t.albedo[:, i]  # Whitted: a metal is a tinted mirror
            elif isinstance(m, Dielectric):
                t.refraction_index[i] = m.refraction_index
            elif isinstance(m, Emissive):
                t.emission[:, i] = plain(m.color, i, t.emission_texture)
            elif isinstance(m, Phong):
                t.albedo[:, i] = m.diffuse
                t.ambient[:, i] = m.ambient
                t.specular[:, i] = m.specular
                t.shininess[i] = m.shininess
                t.reflectivity[:, i] = m.reflectivity
        for name in ("albedo", "fuzz", "refraction_index", "emission", "ambient", "specular", "shininess",
                     "reflectivity"):
            setattr(t, name, getattr(t, name).astype(dtype))
        t.textures = textures if len(textures) else None
        return t

    def code(self, kind: str) -> int:
        return KINDS.index(kind)

    @property
    def needs_uv(self) -> bool:
        """Whether some texture reads the hits' ``uv`` (an image)."""
        return self.textures is not None and self.textures.needs_uv

    def albedo_at(self, material_idx, point, uv) -> np.ndarray:
        """``albedo (3, N)`` of hits on materials ``material_idx (N,)`` at
        ``point (3, N)`` with ``uv (2, N)``: the table's colour, textured rows
        evaluated (exactly the gathered colour when nothing is textured)."""
        return self._textured(self.albedo, self.albedo_texture, material_idx, point, uv)

    def emission_at(self, material_idx, point, uv) -> np.ndarray:
        """Emitted radiance ``(3, N)``, as :meth:`albedo_at`."""
        return self._textured(self.emission, self.emission_texture, material_idx, point, uv)

    def _textured(self, plain, texture, material_idx, point, uv):
        value = gather(plain, material_idx)
        if self.textures is None:
            return value
        node = texture.take(material_idx)
        rows = true_rows(node >= 0)
        if rows.size:
            value[:, rows] = self.textures.evaluate(node.take(rows), gather(point, rows),
                                                    None if uv is None else gather(uv, rows))
        return value


def scatter_lambertian(direction, normal, front_face, albedo, u, out=None):
    """Cosine-weighted diffuse bounce: ``n + random_unit_vector()``.  The
    scattered directions go into ``out`` ``(3, N)`` if given (for each
    kernel here, ``out`` may be ``direction`` itself: it is read first).

    A unit normal plus a uniform point on the unit sphere is distributed with
    density ``cos(theta) / pi`` over the hemisphere (RTIOW 1, "True Lambertian
    Reflection"), so the attenuation is just the albedo.  Never absorbs.
    """
    scattered = random_unit_vector(u[0], u[1])
    if scattered.dtype == np.result_type(scattered, normal):
        scattered += normal  # normal + v in v's array (a sum commutes exactly)
    else:
        scattered = normal + scattered
    squared = dot(scattered, scattered)  # the test's, then normalize's
    degenerate = true_rows(squared < DEGENERATE_SQUARED_LENGTH)
    if degenerate.size:  # rare rows: by index, not a where (and no gather or scatter of none)
        fallback = gather(normal, degenerate)
        scatter(scattered, degenerate, fallback)
        squared[degenerate] = dot(fallback, fallback)  # their new columns' (dot works column by column)
    absorbed = np.zeros(direction.shape[1], dtype=bool)
    return albedo, normalize(scattered, out=scattered if out is None else out, squared_length=squared), absorbed


def lambertian_pdf(normal, direction):
    """The solid-angle density with which :func:`scatter_lambertian` picks
    ``direction``: ``max(cos theta, 0) / pi`` about the same ``normal`` (both
    ``(3, N)`` unit); shape ``(N,)``, float64.  Light sampling's MIS weights
    need it; metal and glass have none (they are deltas)."""
    cos = dot(normal, direction).astype(np.float64, copy=False)  # a new array either way
    np.maximum(cos, 0.0, out=cos)
    cos /= np.pi
    return cos


def lambertian_eval(albedo, normal, direction):
    """The BSDF times the cosine, ``albedo / pi * max(cos theta, 0)``, for
    light arriving from ``direction``; shape ``(3, N)``.  Its ratio to
    :func:`lambertian_pdf` is the albedo, the attenuation the kernel returns."""
    return albedo * lambertian_pdf(normal, direction)


class LazyUniforms:
    """A kernel's uniforms ``(2, N)`` drawn only where it reads them:
    ``draw(rows)`` gives those of rows ``rows`` (indices), ``draw(None)``
    every row's; ``dtype`` is theirs.  (See :func:`scatter_metal`.)"""

    __slots__ = ("draw", "dtype")

    def __init__(self, draw, dtype):
        self.draw, self.dtype = draw, np.dtype(dtype)


def _uniforms(u, rows=None):
    """The uniforms ``(2, R)`` of rows ``rows`` (None: all) of ``u``, a
    ``(2, N)`` array or :class:`LazyUniforms`."""
    if isinstance(u, LazyUniforms):
        return u.draw(rows)
    return u if rows is None else gather(u, rows)


def scatter_metal(direction, normal, front_face, albedo, fuzz, u, out=None):
    """Mirror reflection jittered by ``fuzz * random_unit_vector()``.

    Rows whose scattered direction does not point above the surface
    (``d.n <= 0``) are absorbed, as in the lesson.  ``u``: the uniforms,
    ``(2, N)`` or :class:`LazyUniforms` (perfect mirrors read those of a
    few rows at most).
    """
    reflected = reflect(direction, normal)
    normalize(reflected, out=reflected)
    if not fuzz.any() and np.result_type(fuzz, u.dtype, reflected) == reflected.dtype:
        # Perfect mirrors (gold in RTIOW's scenes): each jitter is a signed
        # zero, and adding one changes no number but a -0 (to +0, where the
        # zero is +0), so only rows with a zero component need theirs.
        scattered = reflected
        rows = true_rows((reflected == 0.0).any(axis=0))
        if rows.size:
            ur = _uniforms(u, rows)
            jitter = gather(fuzz, rows) * random_unit_vector(ur[0], ur[1])
            scatter(scattered, rows, gather(reflected, rows) + jitter)
    else:
        u = _uniforms(u)
        scattered = fuzz * random_unit_vector(u[0], u[1])
        if scattered.dtype == np.result_type(scattered, reflected):
            scattered += reflected  # reflected + jitter in the jitter's array (a sum commutes exactly)
        else:
            scattered = reflected + scattered
    absorbed = dot(scattered, normal) <= 0.0
    return albedo, normalize(scattered, out=scattered if out is None else out), absorbed


def scatter_dielectric(direction, normal, front_face, refraction_index, u, out=None):
    """Reflect with probability Schlick(cos, ratio), else refract (Snell).

    ``ratio`` is 1/index entering through the front face and index leaving;
    where ``ratio * sin(theta) > 1`` there is no refracted ray (total internal
    reflection).  Glass absorbs nothing: attenuation is 1.
    """
    ratio = np.where(front_face, 1.0 / refraction_index, refraction_index)
    # cos = min(-d.n, 1) and sin = sqrt(max(0, 1 - cos^2)), each in its own
    # array in place (the same operations, fewer temporaries)
    cos_theta = dot(direction, normal)
    np.negative(cos_theta, out=cos_theta)
    np.minimum(cos_theta, 1.0, out=cos_theta)
    sin_theta = np.multiply(cos_theta, cos_theta)
    np.subtract(1.0, sin_theta, out=sin_theta)
    np.maximum(0.0, sin_theta, out=sin_theta)
    np.sqrt(sin_theta, out=sin_theta)
    total_internal = ratio * sin_theta > 1.0
    total_internal |= schlick(cos_theta, ratio) > u[0]
    mirror = true_rows(total_internal)
    scattered = refract(direction, normal, ratio, cos_theta)  # the cosine just taken, not again
    # rows that mirror are few and random: write them by index, not with a where
    scatter(scattered, mirror, reflect(gather(direction, mirror), gather(normal, mirror)))
    n = direction.shape[1]
    return (np.ones((3, n), dtype=direction.dtype), normalize(scattered, out=scattered if out is None else out),
            np.zeros(n, dtype=bool))
