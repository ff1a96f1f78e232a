"""The rules a scene's values obey, written once for the Python objects and the scene file.

Every scene object (:class:`~wavefront.geometry.Sphere`, the materials,
:class:`~wavefront.camera.Camera`, ...) checks and normalises its fields in
``__post_init__`` with these helpers, so ``Sphere((0, 0, 0), -1, "m")`` is
refused exactly as ``radius: -1`` in a file is.  A problem is one
:class:`SceneError` naming where the value came from (``<Sphere>`` for an
object built in Python, the file name for a scene file), the path of the
value inside it (``radius``, ``spheres[3].radius``) and what is wrong.  The
scene-file loader re-raises an object's error under the file's name and the
value's YAML path (:meth:`SceneError.within`).
"""

from __future__ import annotations

import math
import numbers
import unicodedata
import warnings

import numpy as np


class SceneError(ValueError):
    """A scene file or value is malformed.

    ``str(error)`` is the whole user-facing message:
    ``source: path: problem``.
    """

    def __init__(self, source: str, path: str, problem: str):
        self.source, self.path, self.problem = source, path, problem
        where = f"{source}: {path}" if path else source
        super().__init__(f"{where}: {problem}")

    def within(self, source: str, prefix: str) -> SceneError:
        """The same problem, seen from a container: ``source`` and ``prefix.path``."""
        return SceneError(source, join(prefix, self.path), self.problem)


class SceneWarning(UserWarning):
    """Something in a scene was accepted but changed or ignored."""


def join(path: str, key: str | int) -> str:
    """``spheres`` + 3 -> ``spheres[3]``; ``camera`` + ``vfov`` -> ``camera.vfov``."""
    if isinstance(key, int):
        return f"{path}[{key}]"
    if not path:
        return key
    if not key:
        return path
    return f"{path}{key}" if key.startswith("[") else f"{path}.{key}"


def source_of(obj) -> str:
    """How an object built in Python is named in its messages: ``<Sphere>``."""
    return f"<{type(obj).__name__}>"


def fail(obj, path: str, problem: str):
    raise SceneError(source_of(obj), path, problem)


def warn(obj, path: str, problem: str) -> None:
    """A SceneWarning that the scene-file loader can re-issue under the file's name and YAML path."""
    warning = SceneWarning(f"{source_of(obj)}: {path}: {problem}")
    warning.path, warning.problem = path, problem
    warnings.warn(warning, stacklevel=4)


_QUOTED_DIGITS = 40  # an integer of more digits is quoted by its length: str() refuses past 4,300


def quote(value) -> str:
    """``repr(value)``, but an integer of more than 40 digits as ``an integer
    of N digits``: YAML reads ``0x`` and 5,000 hex digits as an int whose str()
    raises ValueError (Python's 4,300-digit limit), a traceback in a message."""
    if isinstance(value, numbers.Integral) and not isinstance(value, (bool, np.bool_)):
        value = int(value)
        if value.bit_length() > 3 * _QUOTED_DIGITS:  # > 36 digits: counted without str()
            size = abs(value)
            digits = int((value.bit_length() - 1) * 0.30102999566398120) + 1
            digits += size >= 10 ** digits
            digits -= size < 10 ** (digits - 1)
            if digits > _QUOTED_DIGITS:
                return f"{'a negative' if value < 0 else 'an'} integer of {digits} digits"
    return repr(value)


def describe(value) -> str:
    """``string 'x'``, ``a list of 2 items``: what a wrong value was, briefly."""
    if value is None:
        return "nothing (null)"
    if isinstance(value, YAML11Number):
        return f"{value!s} ({value.reason})"
    kind = {bool: "boolean", int: "integer", float: "number", str: "string",
            list: "list", tuple: "list", dict: "mapping"}.get(type(value), type(value).__name__)
    if isinstance(value, (list, tuple, dict)):
        return f"a {kind} of {len(value)} item{'s' if len(value) != 1 else ''}"
    text = quote(value)
    if text.endswith(" digits"):
        return text
    return f"{kind} {text[:40] + '...' if len(text) > 40 else text}"


class YAML11Number(str):
    """A plain scalar that YAML 1.1 reads as a number and YAML 1.2 reads differently
    (``1:30`` is 90 in 1.1 and text in 1.2; ``010`` is 8 in 1.1 and 10 in 1.2).

    The scene file gives it this type instead of guessing; where a number is
    expected it is refused with ``reason``, where text is expected it is text.
    """

    reason: str

    def __new__(cls, text: str, reason: str):
        self = super().__new__(cls, text)
        self.reason = reason
        return self


def is_number(value) -> bool:
    """A real number, not a boolean (``True`` is an ``int`` to Python, not to a scene)."""
    return isinstance(value, numbers.Real) and not isinstance(value, (bool, np.bool_))


def number(obj, value, path: str, *, low=None, low_open=False, high=None, high_open=False) -> float:
    """``value`` as a finite float within the bounds, or a SceneError at ``path``."""
    if not is_number(value):
        fail(obj, path, f"expected a number, got {describe(value)}")
    try:
        x = float(value)
    except OverflowError:  # an integer beyond float64
        x = math.inf if value > 0 else -math.inf
    if not math.isfinite(x):
        fail(obj, path, f"must be finite, got {quote(value)}")
    if low is not None and (x <= low if low_open else x < low):
        fail(obj, path, f"must be {'>' if low_open else '>='} {low}, got {quote(value)}")
    if high is not None and (x >= high if high_open else x > high):
        fail(obj, path, f"must be {'<' if high_open else '<='} {high}, got {quote(value)}")
    return x


def integer(obj, value, path: str, *, low=None, high=None) -> int:
    """``value`` as an int within the bounds; a float with no fraction (``4.0``) counts."""
    if isinstance(value, numbers.Integral) and not isinstance(value, (bool, np.bool_)):
        value = int(value)
    elif is_number(value) and math.isfinite(value) and float(value).is_integer():
        value = int(value)
    else:
        fail(obj, path, f"expected an integer, got {describe(value)}")
    if low is not None and value < low:
        fail(obj, path, f"must be >= {low}, got {quote(value)}")
    if high is not None and value > high:
        fail(obj, path, f"must be <= {high}, got {quote(value)}")
    return value


def vec3(obj, value, path: str, *, low=None, high=None) -> tuple[float, float, float]:
    """Three numbers (list, tuple or array) as a tuple of floats."""
    if isinstance(value, np.ndarray) and value.ndim == 1:
        value = value.tolist()
    if not isinstance(value, (list, tuple)) or len(value) != 3:
        fail(obj, path, f"expected a list of 3 numbers, got {describe(value)}")
    return tuple(number(obj, v, f"{path}[{i}]", low=low, high=high) for i, v in enumerate(value))


def first_line(e: BaseException) -> str:
    """An exception's message as the end of one line of ours: its first line,
    at most 200 characters, or its type's name when it says nothing."""
    text = str(e).strip().splitlines()
    return text[0][:200] if text else type(e).__name__


# A colour (albedo, emission, background) above this overflows a render's
# float32 arithmetic on its way to the film: an emitter of 1e300 rendered
# black, its samples dropped as non-finite, after NumPy's overflow warnings.
MAX_COLOR = 1e30


def color(obj, value, path: str, *, high=None) -> tuple[float, float, float]:
    """An RGB triple: three finite numbers >= 0 and <= ``MAX_COLOR`` (or ``high``)."""
    return vec3(obj, value, path, low=0.0, high=MAX_COLOR if high is None else min(high, MAX_COLOR))


def string(obj, value, path: str, choices=None) -> str:
    if not isinstance(value, str):
        fail(obj, path, f"expected a string, got {describe(value)}")
    value = str(value)  # a YAML11Number where text is expected is just its text
    if choices is not None and value not in choices:
        fail(obj, path, f"unknown value {value!r} (expected one of: {', '.join(choices)})")
    return value


def file_name(obj, value, path: str) -> str:
    """A file's name: a string without a NUL byte, which no file name holds
    (os.stat raised ValueError on it: a traceback, not a message)."""
    value = string(obj, value, path)
    if "\0" in value:
        fail(obj, path, f"a file name cannot hold a NUL byte, got {value!r}")
    return value


def name(obj, value, path: str) -> str:
    """A material name, in Unicode NFC so that names which look the same are the same."""
    return unicodedata.normalize("NFC", string(obj, value, path))


def instance(obj, value, path: str, kinds: type | tuple[type, ...], what: str):
    if not isinstance(value, kinds):
        fail(obj, path, f"expected {what}, got {describe(value)}")
    return value
