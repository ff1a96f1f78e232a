"""Reading scene files: YAML in, a validated :class:`~wavefront.scene.Scene` out.

Every problem is reported as one :class:`SceneError` naming the file, the YAML
path of the offending value (``spheres[3].material``) and what is wrong.

Reading is in two steps.  First the YAML becomes plain Python values
(:func:`read_yaml`): libyaml's C parser (PyYAML's pure-Python one where PyYAML
was built without libyaml) streams events, and plain values are built from
them directly, without PyYAML's node tree (which costs ~5 KB a sphere).  On
the way, scalars are typed by YAML 1.2's core schema, duplicate keys are
errors, nesting is bounded, and aliases are counted by the values they expand
to, so a "billion laughs" file is refused while a large file without aliases
is only bounded by its size.  Then the values become scene objects
(:func:`scene_from_dict`): the loader checks the document's shape (mappings,
known keys) and hands the values to the objects' constructors, which hold the
rules (``wavefront.validation``); their errors come back here under the file's
name and the value's YAML path.
"""

from __future__ import annotations

import contextlib
import dataclasses
import functools
import gc
import math
import operator
import os
import re
import sys
import unicodedata
import warnings
from itertools import repeat
from typing import Any

import yaml
from yaml.events import (AliasEvent, DocumentEndEvent, MappingEndEvent, ScalarEvent, SequenceEndEvent,
                         SequenceStartEvent, StreamEndEvent)
from yaml.nodes import ScalarNode

from .background import Sky, Solid
from .camera import Camera
from .geometry import Sphere
from .scene import (  # noqa: F401  (the limits are importable from here too, as before)
    MATERIAL_TYPES, MAX_DEPTH, MAX_PIXELS, MAX_SAMPLES_PER_PIXEL, MAX_SEED, PointLight, RenderSettings, Scene,
    unknown_material,
)
from .media import Medium, box_faces
from .shapes import Box, Mesh, MeshError, Quad, Triangle, read_mesh
from .memory import LOAD_BYTES_PER_FILE_BYTE, MemoryBudgetError, check_budget, current_rss, refuse_unless_fits
from .textures import image_load_bytes, images_shared
from .shapes import mesh as mesh_files
from .shapes.mesh import mesh_fields
from .validation import SceneError, SceneWarning, YAML11Number, describe, file_name, join, string

__all__ = ["MAX_DEPTH", "MAX_PIXELS", "MAX_SAMPLES_PER_PIXEL", "MAX_SEED", "SceneError", "SceneWarning",
           "load_scene", "read_yaml", "scene_from_dict"]

MiB = 1 << 20
# A million spheres written as make_final_scene.py writes them is ~68 MB and
# loads in ~14 s and ~520 MiB (benchmarks/scene_loading.py); MAX_VALUES below
# stops a file at ~1.45 million spheres, this at ~1.9 million.
MAX_FILE_BYTES = 128 * MiB
MAX_ALIAS_VALUES = 2_000_000  # values that aliases may add by expansion ("billion laughs" guard)
# Values (keys, scalars, lists, mappings) the document itself may hold: bounds
# memory where bytes alone do not (``[[], [], ...]`` is ~60 bytes of Python
# per 3 bytes of file).  A million spheres are ~11 million values.
MAX_VALUES = 16_000_000
# ... and what each may cost while the scene is built: ~47 bytes a value on
# average for a million spheres (11 million values, ~520 MiB), ~64 for an
# empty list (its object and its slot in the parent).  With a memory budget
# the document may hold only as many values as the budget has room for at
# this size, counted as they are built, so a file of many small values
# ([[], [], ...], 3 bytes each: 12 MB took 339 MiB) is refused near the
# budget, not past twice it.
YAML_BYTES_PER_VALUE = 64
MAX_NESTING = 64  # no valid scene nests deeper than ~4
MAX_NODES = MAX_ALIAS_VALUES  # the old name of the alias limit


# ---------------------------------------------------------------------------
# YAML 1.2 core schema

_TAG = "tag:yaml.org,2002:"
_YAML11 = "tag:wavefront,2026:yaml-1.1-number"


class _Resolver(yaml.resolver.BaseResolver):
    """Implicit types of YAML 1.2's core schema, not PyYAML's YAML 1.1 ones.

    YAML 1.1 reads ``1e6`` as text, ``yes`` as true, ``1:30`` as 90 and
    ``010`` as 8; YAML 1.2 reads them as 1000000.0, text, text and 10.  The
    1.2 rules are followed, and the plain scalars the two versions read as
    different numbers are typed ``_YAML11`` so that the scene refuses them,
    with the reason, wherever it expects a number.
    """


    def resolve(self, kind, value, implicit):
        """BaseResolver.resolve for plain scalars without its per-call list
        concatenation (it runs for every number in the file)."""
        if kind is ScalarNode and implicit[0]:
            for tag, regexp in self.yaml_implicit_resolvers.get(value[:1], ()):
                if regexp.match(value):
                    return tag
            return self.DEFAULT_SCALAR_TAG
        return super().resolve(kind, value, implicit)


_DIGITS = "-+0123456789"
for _tag, _pattern, _first in [
    # YAML 1.2 core schema, section 10.3.2; integers with a leading zero are
    # left to the YAML 1.1 patterns below
    (_TAG + "float", r"[-+]?(?:(?:\.[0-9]+|[0-9]+\.[0-9]*)(?:[eE][-+]?[0-9]+)?|[0-9]+[eE][-+]?[0-9]+)", _DIGITS + "."),
    (_TAG + "int", r"[-+]?(?:0|[1-9][0-9]*)|0o[0-7]+|0x[0-9a-fA-F]+", _DIGITS),
    (_TAG + "float", r"[-+]?\.(?:inf|Inf|INF)|\.(?:nan|NaN|NAN)", "-+."),
    (_TAG + "null", r"~|null|Null|NULL|", ["~", "n", "N", ""]),
    (_TAG + "bool", r"true|True|TRUE|false|False|FALSE", "tTfF"),
    # YAML 1.1 numbers that YAML 1.2 reads differently (or not as numbers)
    (_YAML11, r"[-+]?[0-9][0-9_]*(?::[0-5]?[0-9])+(?:\.[0-9_]*)?", _DIGITS),  # sexagesimal 1:30
    (_YAML11, r"[-+]?0[0-9_]+", _DIGITS),  # leading zero: octal in 1.1
    (_YAML11, r"[-+]?0b[01_]+", _DIGITS),  # binary in 1.1
    (_YAML11, r"[-+]?(?:0x[0-9a-fA-F_]*_[0-9a-fA-F_]*|[0-9][0-9_]*_[0-9_]*(?:\.[0-9_]*)?"
              r"(?:[eE][-+]?[0-9]+)?|[0-9][0-9_]*\.[0-9]*_[0-9_]*(?:[eE][-+]?[0-9]+)?)", _DIGITS),  # 1_000
]:
    _Resolver.add_implicit_resolver(_tag, re.compile(f"^(?:{_pattern})$"), list(_first))

class _PythonParser(yaml.reader.Reader, yaml.scanner.Scanner, yaml.parser.Parser, _Resolver):
    """PyYAML's pure-Python parser, with the same resolver (for PyYAML built without libyaml)."""

    def __init__(self, stream):
        yaml.reader.Reader.__init__(self, stream)
        yaml.scanner.Scanner.__init__(self)
        yaml.parser.Parser.__init__(self)
        _Resolver.__init__(self)


if yaml.__with_libyaml__:
    class _CParser(yaml.cyaml.CParser, _Resolver):
        """libyaml's C parser (events only; values are built by ``_Builder``)."""

        def __init__(self, stream):
            yaml.cyaml.CParser.__init__(self, stream)
            _Resolver.__init__(self)

    _Parser = _CParser
else:  # pragma: no cover - PyYAML built without libyaml
    _Parser = _PythonParser


def _yaml11(text: str) -> YAML11Number:
    """Why ``text`` is refused as a number: what YAML 1.1 and 1.2 make of it."""
    body = text.lstrip("+-").replace("_", "")
    sign = -1 if text.startswith("-") else 1
    if ":" in body:
        value = 0.0 if "." in body else 0
        for part in body.split(":"):
            value = value * 60 + (float(part) if "." in part else int(part))
        old = sign * value
        return YAML11Number(text, f"YAML 1.1 reads it as the base-60 number {old}, YAML 1.2 as text; "
                                  f"write {old} if that is what you mean")
    if body.startswith("0b"):
        return YAML11Number(text, f"YAML 1.1 reads it as binary {sign * int(body[2:] or '0', 2)}, "
                                  "YAML 1.2 as text")
    if "_" in text:
        return YAML11Number(text, f"YAML 1.1 reads it as {body if sign > 0 else '-' + body}, YAML 1.2 as text: "
                                  "YAML 1.2 numbers have no digit separators")
    decimal = sign * int(body)
    if all(c in "01234567" for c in body):
        return YAML11Number(text, f"YAML 1.1 reads it as octal {sign * int(body, 8)}, YAML 1.2 as {decimal}; "
                                  f"write {decimal}, or 0o{body.lstrip('0') or '0'} for octal")
    return YAML11Number(text, f"YAML 1.2 reads it as {decimal}, YAML 1.1 as text (a leading zero marks "
                              f"octal there); write {decimal}")


def _integer(text: str) -> int:
    if text[:2] in ("0o", "0x"):
        return int(text, 0)
    return int(text)


def _float(text: str) -> float:
    try:
        return float(text)  # every YAML 1.2 float but the spellings below
    except ValueError:
        if text.lower().endswith(".inf"):
            return -math.inf if text.startswith("-") else math.inf
        return math.nan  # .nan, .NaN, .NAN


_CONSTRUCT = {
    _TAG + "null": lambda text: None,
    _TAG + "bool": lambda text: text.lower() == "true",
    _TAG + "int": _integer,
    _TAG + "float": _float,
    _TAG + "str": str,
    _YAML11: _yaml11,
}


class _Problem(Exception):
    """A YAML-level problem; the path is collected as it propagates outwards."""

    def __init__(self, problem: str, mark=None):
        super().__init__(problem)
        self.problem, self.mark, self.parts = problem, mark, []

    def path(self) -> str:
        path = ""
        for part in reversed(self.parts):
            path = join(path, part if isinstance(part, int) else str(part))
        return path


_MISSING = object()
_PLAIN = (True, False)  # the ``implicit`` of a plain scalar without a tag
_CACHE_LIMIT = 1 << 16  # plain scalars remembered (keys, repeated values); random coordinates are not


class _OverBudget(Exception):
    """The document holds more values than the memory budget has room for."""


def _unreadable_number(text: str, e: ValueError) -> str:
    """Why a number cannot be read, for a message: Python's own words for an
    integer past its digit limit ended in advice to call
    sys.set_int_max_str_digits(), which a scene's author cannot."""
    shown = repr(text[:40]) + ("..." if len(text) > 40 else "")
    if "Exceeds the limit" in str(e):
        digits = sum(c.isdigit() for c in text)
        return (f"cannot read {shown}: an integer of {digits:,} digits (at most "
                f"{sys.get_int_max_str_digits():,} can be read)")
    return f"cannot read {shown}: {e}"


class _Builder:
    """Plain Python values from a parser's events (one document).

    Collections count their depth; an anchored value's expanded size is
    measured once (shared parts memoised) and every alias to it adds that
    size to ``aliased``, so expansion is bounded without being performed.
    Aliases share the anchored value, as PyYAML's constructor does.
    """

    def __init__(self, parser, max_values: int):
        self.max_values = max_values
        self.get_event = parser.get_event
        self.resolve = parser.resolve
        self.anchors: dict[str, tuple[Any, int]] = {}
        self.anchored_sizes: dict[int, int] = {}  # id(anchored collection) -> expanded size
        self.open_anchors: set[str] = set()
        self.aliased = 0
        self.values = 0  # in collections that are complete, counted at their end (not per value: speed)
        self.cache: dict[str, Any] = {}

    def document(self) -> Any:
        get = self.get_event
        get()  # StreamStart
        event = get()
        if type(event) is StreamEndEvent:
            return _MISSING
        value = self.value(get(), 0)
        if type(get()) is not DocumentEndEvent:
            raise _Problem("expected the end of the document")
        if type(get()) is not StreamEndEvent:
            raise _Problem("the file holds more than one YAML document")
        return value

    def value(self, event, depth: int) -> Any:
        kind = type(event)
        if kind is ScalarEvent:
            return self.scalar(event)
        if kind is AliasEvent:
            return self.alias(event)
        if depth >= MAX_NESTING:
            raise _Problem(f"nested more than {MAX_NESTING} levels deep", event.start_mark)
        if event.tag is not None and event.tag not in ("!", _TAG + ("seq" if kind is SequenceStartEvent else "map")):
            raise _Problem(f"unsupported tag {event.tag!r}", event.start_mark)
        anchor = event.anchor
        if anchor is not None:
            self.open_anchors.add(anchor)
        value = self.sequence(depth) if kind is SequenceStartEvent else self.mapping(depth)
        if anchor is not None:
            self.open_anchors.discard(anchor)
            size = _expanded_size(value, {}, self.anchored_sizes)
            self.anchors[anchor] = (value, size)
            self.anchored_sizes[id(value)] = size  # the value stays alive in anchors: its id is stable
        return value

    def count(self, values: int, event) -> None:
        self.values += values + 1
        if self.values > self.max_values:
            if self.max_values < MAX_VALUES:
                raise _OverBudget(self.max_values)
            raise _Problem(f"the document holds more than {MAX_VALUES} values (a million spheres are about "
                           "11 million); the limit bounds the memory a scene file can take", event.start_mark)

    def alias(self, event) -> Any:
        name = event.anchor
        if name in self.open_anchors:
            raise _Problem(f"alias *{name} refers to a value that contains it", event.start_mark)
        if name not in self.anchors:
            raise _Problem(f"alias *{name} refers to no anchor &{name} before it", event.start_mark)
        value, size = self.anchors[name]
        self.aliased += size
        if self.aliased > MAX_ALIAS_VALUES:
            raise _Problem(f"aliases expand the document by more than {MAX_ALIAS_VALUES} values "
                           "(alias bomb?)", event.start_mark)
        return value

    def scalar(self, event) -> Any:
        text, tag = event.value, event.tag
        if tag is None and event.implicit[0]:  # plain: typed by the resolver
            value = self.cache.get(text, _MISSING)
            if value is _MISSING:
                try:  # every tag the resolver gives has a constructor
                    value = _CONSTRUCT[self.resolve(ScalarNode, text, _PLAIN)](text)
                except ValueError as e:  # an integer of more than 4300 digits
                    raise _Problem(_unreadable_number(text, e), event.start_mark) from None
                if len(self.cache) < _CACHE_LIMIT:
                    self.cache[text] = value
        elif tag is None or tag == "!":  # quoted, or the non-specific tag: text
            value = text
        else:
            value = self.construct(tag, text, event)
        if event.anchor is not None:
            self.anchors[event.anchor] = (value, 1)
        return value

    def construct(self, tag: str, text: str, event) -> Any:
        """A scalar with an explicit tag (``!!float 1``): the text must be one the tag's type reads."""
        make = _CONSTRUCT.get(tag)
        if make is None or tag == _YAML11:
            raise _Problem(f"unsupported tag {tag!r}", event.start_mark)
        implicit = self.resolve(ScalarNode, text, _PLAIN)
        if tag != _TAG + "str" and tag != implicit and not (tag == _TAG + "float" and implicit == _TAG + "int"):
            raise _Problem(f"{text!r} is not a valid {tag.removeprefix(_TAG)}", event.start_mark)
        try:
            return make(text)
        except ValueError as e:  # an integer of more than 4300 digits
            raise _Problem(_unreadable_number(text, e), event.start_mark) from None

    def sequence(self, depth: int) -> list:
        items: list = []
        append, get, scalar, cached = items.append, self.get_event, self.scalar, self.cache.get
        try:
            while True:
                event = get()
                kind = type(event)
                if kind is ScalarEvent:
                    # a plain scalar seen before (keys, repeated values): no call
                    value = cached(event.value, _MISSING) if event.tag is None and event.anchor is None \
                        and event.implicit[0] else _MISSING
                    append(scalar(event) if value is _MISSING else value)
                elif kind is SequenceEndEvent:
                    self.count(len(items), event)
                    return items
                else:
                    append(self.value(event, depth + 1))
        except _Problem as p:
            p.parts.append(len(items))
            raise

    def mapping(self, depth: int) -> dict:
        items: dict = {}
        get, scalar, cached = self.get_event, self.scalar, self.cache.get
        key = _MISSING
        try:
            while True:
                event = get()
                kind = type(event)
                if kind is MappingEndEvent:
                    self.count(2 * len(items), event)
                    return items
                key = _MISSING
                if kind is ScalarEvent:
                    key = cached(event.value, _MISSING) if event.tag is None and event.anchor is None \
                        and event.implicit[0] else _MISSING
                    if key is _MISSING:
                        key = scalar(event)
                else:
                    key = self.value(event, depth + 1)
                try:
                    duplicate = key in items
                except TypeError:
                    raise _Problem(f"a key must be a single value, not {describe(key)}", event.start_mark) from None
                if duplicate:
                    raise _Problem("duplicate key", event.start_mark)
                event = get()
                if type(event) is ScalarEvent:
                    value = cached(event.value, _MISSING) if event.tag is None and event.anchor is None \
                        and event.implicit[0] else _MISSING
                    items[key] = scalar(event) if value is _MISSING else value
                else:
                    items[key] = self.value(event, depth + 1)
        except _Problem as p:
            if key is not _MISSING:
                p.parts.append(key if isinstance(key, str) else repr(key))
            raise


def _expanded_size(value, memo: dict[int, int], anchored: dict[int, int]) -> int:
    """Values in ``value`` once every alias inside it is expanded (linear time)."""
    key = id(value)
    if key in anchored:
        return anchored[key]
    if key in memo:
        return memo[key]
    if isinstance(value, list):
        size = 1 + sum(_expanded_size(v, memo, anchored) for v in value)
    elif isinstance(value, dict):
        size = 1 + sum(_expanded_size(k, memo, anchored) + _expanded_size(v, memo, anchored)
                       for k, v in value.items())
    else:
        return 1
    memo[key] = size
    return size


def _size_text(size: int) -> str:
    return f"{size / MiB:.1f} MiB ({size / 1e6:.1f} MB)"


def read_yaml(data: bytes, source: str, *, size: int | None = None, max_values: int | None = None) -> Any:
    """Parse YAML bytes safely into plain values, raising :class:`SceneError` on any problem.

    ``size`` is the file's size when known (``data`` may hold only the first
    ``MAX_FILE_BYTES + 1`` bytes of it).  A document of more than
    ``max_values`` values (below ``MAX_VALUES``: what a memory budget holds)
    raises :class:`MemoryBudgetError`.
    """
    if len(data) > MAX_FILE_BYTES:
        actual = (f"is {_size_text(size)}" if size and size > MAX_FILE_BYTES
                  else f"is larger than {MAX_FILE_BYTES // MiB} MiB")
        raise SceneError(source, "", f"file {actual}; the limit is {MAX_FILE_BYTES // MiB} MiB")
    try:
        data.decode("utf-8")  # libyaml reads bytes itself; this only finds a bad byte early, with its offset
    except UnicodeDecodeError as e:
        raise SceneError(source, "", f"not UTF-8 text (byte {e.start}: {data[e.start:e.start + 1]!r})") from None
    parser = None
    try:
        parser = _Parser(data)
        value = _Builder(parser, MAX_VALUES if max_values is None else max_values).document()
    except _OverBudget as e:
        raise MemoryBudgetError(f"{source}: the document holds more than {e.args[0]:,} values, about "
                                f"{YAML_BYTES_PER_VALUE} bytes each to load: more than the memory budget "
                                "has room for") from None
    except _Problem as p:
        where = f" (line {p.mark.line + 1}, column {p.mark.column + 1})" if p.mark is not None else ""
        raise SceneError(source, p.path(), f"{p.problem}{where}") from None
    except yaml.YAMLError as e:
        mark = getattr(e, "problem_mark", None)
        where = f" (line {mark.line + 1}, column {mark.column + 1})" if mark else ""
        problem = getattr(e, "problem", None) or str(e).splitlines()[0]
        raise SceneError(source, "", f"invalid YAML{where}: {problem}") from None
    except RecursionError:
        raise SceneError(source, "", "YAML nested too deeply") from None
    finally:
        if parser is not None and hasattr(parser, "dispose"):
            parser.dispose()
    if value is _MISSING:
        raise SceneError(source, "", "the file is empty")
    return value


def load_scene(path: str | os.PathLike, *, memory: int | None = None) -> Scene:
    """Read and validate a YAML scene file.

    Raises
    ------
    SceneError
        Naming the file, the YAML path and the problem.
    ValueError
        If ``memory`` is not a budget :func:`wavefront.render_scene` accepts.
    """
    source = os.fsdecode(path)  # a bytes path too: the messages and the mesh paths are text
    if memory is not None:
        memory = check_budget(memory)  # ValueError, as render_scene's
    try:
        with open(source, "rb") as f:
            try:
                st = os.fstat(f.fileno())
                size = st.st_size
            except OSError:
                size = None
            if size and size > MAX_FILE_BYTES:  # refuse before reading a huge file
                raise SceneError(source, "", f"file is {_size_text(size)}; the limit is {MAX_FILE_BYTES // MiB} MiB")
            # a pipe or device has no size: read in chunks, each checked
            # (the command checked a file's size before reading it)
            data = f.read(MAX_FILE_BYTES + 1) if size else _read_stream(f, source, memory)
    except OSError as e:
        raise SceneError(source, "", f"cannot read: {e.strerror or e}") from None
    name = os.path.splitext(os.path.basename(source))[0]
    with _collector_paused(), images_shared():
        room = None if memory is None else min(MAX_VALUES, max(0, memory - current_rss()) // YAML_BYTES_PER_VALUE)
        doc = read_yaml(data, source, size=size, max_values=room)
        del data
        return _scene_from_document(doc, source, name, consume=True, memory=memory, base=_relative_to(source))


STREAM_CHUNK = 1 << 20  # a pipe is read this much at a time, the budget checked after each


def _read_stream(f, source: str, memory: int | None) -> bytes:
    """Up to ``MAX_FILE_BYTES + 1`` bytes of a file without a size (a pipe,
    ``/dev/stdin``, a character device), in chunks: with a ``memory``
    budget, refused (:class:`MemoryBudgetError`) as soon as what has been
    read could not be loaded within it, not after reading it all.

    The bytes read are already in this process's memory, so the check adds
    only the rest of what loading them takes: the same bound as a file's,
    checked before it is read (a 19 MiB scene that loaded from a file under
    ``--memory 200M`` was refused through ``/dev/stdin`` when they were
    counted twice)."""
    buffer = bytearray()
    while len(buffer) <= MAX_FILE_BYTES:
        chunk = f.read(min(STREAM_CHUNK, MAX_FILE_BYTES + 1 - len(buffer)))
        if not chunk:
            break
        buffer += chunk
        del chunk
        if memory is not None:
            refuse_unless_fits(memory, (LOAD_BYTES_PER_FILE_BYTE - 1) * len(buffer),
                               f"loading {source} ({len(buffer) / MiB:,.0f} MiB read so far)")
    return bytes(buffer)


# Paths that name an open file descriptor (bash's <(...) is /dev/fd/63,
# /dev/stdin is /proc/self/fd/0): a scene read there has no directory of its
# own (/dev or /dev/fd means nothing to a mesh path)
_DESCRIPTOR_PATH = re.compile(r"/dev/(?:stdin|stdout|stderr|fd/[0-9]+)"
                              r"|/proc/(?:self|thread-self|[0-9]+)(?:/task/[0-9]+)?/fd/[0-9]+")


def _relative_to(source: str) -> str:
    """The directory a scene file's relative paths (meshes, textures) are
    resolved against: the file's own, or the current directory ("") for a
    scene read through a path that names a file descriptor (``/dev/stdin``,
    ``/dev/fd/N``, ``/proc/*/fd/N``).  A named FIFO is a file in a
    directory like any other: its own directory, as for a regular file."""
    if _DESCRIPTOR_PATH.fullmatch(os.path.abspath(source)):
        return ""
    return os.path.dirname(source)


@contextlib.contextmanager
def _collector_paused():
    """Pause the cyclic garbage collector while a scene is built.

    A million spheres are millions of new containers, and each batch of them
    sets off a collection that walks everything alive: ~25 % of the load
    time.  What is built here holds no reference cycles (recursive aliases are
    refused), so nothing is left for the collector to find.
    """
    enabled = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        if enabled:
            gc.enable()


# ---------------------------------------------------------------------------
# The document's shape; the values' rules are the objects' own.

def _mapping(source: str, value, path: str, allowed, required=()) -> dict:
    if value is None:
        value = {}
    if not isinstance(value, dict):
        raise SceneError(source, path, f"expected a mapping, got {describe(value)}")
    for key in value:
        if not isinstance(key, str):
            raise SceneError(source, path, f"keys must be strings, got {describe(key)}")
        if key not in allowed:
            if key == "<<":
                raise SceneError(source, join(path, key), "merge keys (<<) are YAML 1.1, not 1.2; "
                                                          "write the keys out, or alias the whole mapping")
            raise SceneError(source, join(path, key), f"unknown key (expected one of: {', '.join(sorted(allowed))})")
    for key in sorted(required):
        if key not in value:
            raise SceneError(source, join(path, key), "required key is missing")
    return value


@functools.cache  # asked for every material and shape of a file: ~3,000 times for the cover's 487 spheres
def _fields(cls) -> tuple[frozenset[str], frozenset[str]]:
    """A dataclass's keys in a file: (all, required)."""
    fields = dataclasses.fields(cls)
    required = frozenset(f.name for f in fields
                         if f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING)
    return frozenset(f.name for f in fields), required


def _build(source: str, path: str, cls, spec: dict, **fixed):
    """``cls(**spec)``, its errors and warnings re-issued under ``source`` and ``path``."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", SceneWarning)
        try:
            obj = cls(**spec, **fixed)
        except SceneError as e:
            raise e.within(source, path) from None
    for w in caught:
        if issubclass(w.category, SceneWarning) and hasattr(w.message, "path"):
            warnings.warn(SceneWarning(f"{source}: {join(path, w.message.path)}: {w.message.problem}"), stacklevel=4)
        else:
            warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
    return obj


def _object(source: str, value, path: str, cls, extra=frozenset()):
    allowed, required = _fields(cls)
    spec = _mapping(source, value, path, allowed | extra, required)
    return _build(source, path, cls, {k: v for k, v in spec.items() if k not in extra})


_MATERIALS = {cls.kind: cls for cls in MATERIAL_TYPES}
_BACKGROUNDS = {cls.type: cls for cls in (Sky, Solid)}
_SPHERE_KEYS = frozenset({"center", "radius", "material"})  # the bulk path: spheres without transforms
# Scene's names -> YAML paths ("shapes" is the scene as a whole)
_SCENE_PATHS = {"width": "image.width", "height": "image.height", "": "image", "shapes": ""}


def _typed(source: str, value, path: str, kinds: dict, default=None):
    """An object chosen by the mapping's ``type`` key."""
    spec = _mapping(source, value, path, {"type"} | set().union(*(_fields(c)[0] for c in kinds.values())),
                    () if default else {"type"})
    kind = spec.get("type", default)
    try:
        kind = string(None, kind, "type", tuple(kinds))
    except SceneError as e:
        raise e.within(source, path) from None
    return _object(source, spec, path, kinds[kind], extra={"type"})


def scene_from_dict(doc: Any, *, source: str = "<scene>", default_name: str = "scene") -> Scene:
    """Validate a parsed scene document and build the :class:`Scene`."""
    return _scene_from_document(doc, source, default_name, consume=False)


def _scene_from_document(doc: Any, source: str, default_name: str, *, consume: bool,
                         memory: int | None = None, base: str | None = None) -> Scene:
    """``base``: the directory relative paths are resolved against (default:
    ``source``'s, none for a ``<name>``)."""
    if base is None:
        base = "" if source.startswith("<") else os.path.dirname(source)
    top = _mapping(source, doc, "", {"name", "image", "camera", "render", "background", "materials",
                                     "spheres", "quads", "boxes", "triangles", "meshes", "media", "lights",
                                     "ambient"})
    image = _mapping(source, top.get("image"), "image", {"width", "height"})
    if isinstance(top.get("render"), dict) and top["render"].get("russian_roulette", False) is None:
        # an empty value (say, its depth line commented out) is not "off": RenderSettings reads None so
        raise SceneError(source, "render.russian_roulette",
                         "expected false, true or a mapping like {depth: 5}, got an empty value")
    render = _object(source, top.get("render"), "render", RenderSettings)
    camera = _object(source, top.get("camera"), "camera", Camera)
    background = _typed(source, top.get("background"), "background", _BACKGROUNDS, default="sky")

    materials_doc = top.get("materials") or {}
    if not isinstance(materials_doc, dict):
        raise SceneError(source, "materials",
                         f"expected a mapping of names to materials, got {describe(materials_doc)}")
    materials = {}
    for key, spec in materials_doc.items():
        if not isinstance(key, str):
            raise SceneError(source, "materials", f"material names must be strings, got {describe(key)}")
        spec = _texture_files(spec, base)
        if memory is not None:
            _refuse_images_beyond(memory, source, f"materials.{key}", spec)
        materials[key] = _typed(source, spec, f"materials.{key}", _MATERIALS)

    defined = {unicodedata.normalize("NFC", key) for key in materials}
    spheres_doc = top.get("spheres")
    if consume:  # load_scene's document: let the per-sphere mappings go as soon as they are read
        top["spheres"] = None
    spheres = _spheres(source, spheres_doc if spheres_doc is not None else [], defined, consume)
    del spheres_doc
    quads = _shapes(source, top.get("quads"), "quads", Quad, defined)
    for i, box in enumerate(_shapes(source, top.get("boxes"), "boxes", Box, defined)):
        try:
            quads.extend(box_faces(box, box, ""))
        except SceneError as e:
            raise e.within(source, f"boxes[{i}]") from None
    triangles = _shapes(source, top.get("triangles"), "triangles", Triangle, defined)
    meshes = _meshes(source, top.get("meshes"), defined, memory, base=base)
    media = _media(source, top.get("media"), memory, faces=sum(m.faces.shape[0] for m in meshes), base=base)

    lights_doc = top.get("lights") or []
    if not isinstance(lights_doc, list):
        raise SceneError(source, "lights", f"expected a list, got {describe(lights_doc)}")
    lights = []
    for i, spec in enumerate(lights_doc):
        path = f"lights[{i}]"
        spec = _mapping(source, spec, path, _fields(PointLight)[0] | {"type"}, _fields(PointLight)[1])
        try:
            string(None, spec.get("type", "point"), "type", ("point",))
        except SceneError as e:
            raise e.within(source, path) from None
        lights.append(_object(source, spec, path, PointLight, extra={"type"}))

    fields = {"spheres": spheres, "quads": quads, "triangles": triangles, "meshes": meshes,
              "materials": materials, "camera": camera, "render": render, "background": background,
              "lights": tuple(lights), "media": media}
    for key in ("width", "height"):
        if key in image:
            fields[key] = image[key]
    for key in ("ambient", "name"):
        if key in top:
            fields[key] = top[key]
    fields.setdefault("name", default_name)
    try:
        scene = Scene(**fields)
    except SceneError as e:
        path, _, rest = e.path.partition(".")
        given = [key for key in ("width", "height") if key in image]
        if path == "" and len(given) == 1:  # too many pixels: the one side the file sets (the other is a default)
            path = f"image.{given[0]}"
        else:
            path = _SCENE_PATHS.get(path, path)
        raise SceneError(source, path + (f".{rest}" if rest and path else rest), e.problem) from None

    if render.integrator == "path" and (lights or "ambient" in top):
        warnings.warn(f"{source}: lights/ambient are ignored by the path integrator "
                      "(it is lit by emissive shapes and the background)", SceneWarning, stacklevel=3)
    return scene


def _texture_files(spec, base: str):
    """A material's mapping with every image texture's ``file`` (in its
    colours, and nested in checkers) made relative to the scene file's
    directory, as mesh files are; anything malformed is left for the
    texture's own checks to report."""
    if not base or not isinstance(spec, dict):
        return spec

    def resolve(value):
        if not isinstance(value, dict):
            return value
        value = {k: resolve(v) if k in ("even", "odd") else v for k, v in value.items()}
        if value.get("type") == "image" and isinstance(value.get("file"), str):
            value["file"] = os.path.join(base, value["file"])
        return value

    return {k: resolve(v) if k in ("albedo", "color") else v for k, v in spec.items()}


def _refuse_images_beyond(memory: int, source: str, path: str, spec) -> None:
    """With a memory budget, an image texture too big to load within it is
    refused from its header, before it is decoded (:class:`MemoryBudgetError`),
    as a mesh file is."""
    def walk(value, at):
        if not isinstance(value, dict):
            return
        for side in ("even", "odd"):
            walk(value.get(side), f"{at}.{side}")
        if value.get("type") == "image" and isinstance(value.get("file"), str):
            need = image_load_bytes(value["file"])
            if need is not None:
                refuse_unless_fits(memory, need, f"{source}: {at}.file: loading {value['file']}")

    if isinstance(spec, dict):
        for key in ("albedo", "color"):
            walk(spec.get(key), f"{path}.{key}")


# References to the spheres list while _spheres reads it, when no alias
# shares it: the caller's variable, the argument, and getrefcount's own
_UNSHARED_REFERENCES = 3


def _spheres(source: str, docs, defined: set[str], consume: bool) -> list[Sphere]:
    """The ``spheres`` list: in bulk when every entry is a mapping of exactly
    center, radius and material (see ``Sphere.many``), else one at a time.
    Either way the first problem in the file's order is the one reported."""
    if not isinstance(docs, list):
        raise SceneError(source, "spheres", f"expected a list, got {describe(docs)}")
    if set(map(type, docs)) <= {dict} and all(map(operator.eq, map(dict.keys, docs), repeat(_SPHERE_KEYS))) \
            and set(map(type, materials := list(map(operator.itemgetter("material"), docs)))) <= {str}:
        centers = list(map(operator.itemgetter("center"), docs))
        radii = list(map(operator.itemgetter("radius"), docs))
        unknown = {m for m in {m for m in materials if isinstance(m, str)}
                   if unicodedata.normalize("NFC", m) not in defined}
        end = next(i for i, m in enumerate(materials) if isinstance(m, str) and m in unknown) if unknown else None
        # the list itself is let go only when nothing else holds it: an alias
        # (quads: *spheres) shares it, and must still see its entries
        if consume and hasattr(sys, "getrefcount") and sys.getrefcount(docs) <= _UNSHARED_REFERENCES:
            docs.clear()
        try:
            spheres = Sphere.many(centers[:end], radii[:end], materials[:end])
        except SceneError as e:
            raise e.within(source, "spheres") from None
        if unknown:
            raise SceneError(source, f"spheres[{end}].material", unknown_material(materials[end], defined))
        return spheres
    return _shapes(source, docs, "spheres", Sphere, defined)


def _shapes(source: str, docs, key: str, cls, defined: set[str]) -> list:
    """A list of shapes of one kind, each built (and so checked) by its class,
    its material checked against the scene's."""
    if docs is None:
        return []
    if not isinstance(docs, list):
        raise SceneError(source, key, f"expected a list, got {describe(docs)}")
    allowed, required = _fields(cls)
    shapes = []
    for i, spec in enumerate(docs):
        path = f"{key}[{i}]"
        spec = _mapping(source, spec, path, allowed, required)
        _material_name(source, path, spec)
        shape = _build(source, path, cls, spec)
        _check_reference(source, path, shape.material, defined)
        shapes.append(shape)
    return shapes


def _material_name(source: str, path: str, spec: dict) -> None:
    """A scene file names a shape's material (``material: NAME``); an
    unquoted number is not taken as an index into the materials (the
    Python API's ``material=0`` still is)."""
    value = spec.get("material")
    if value is not None and not isinstance(value, str):
        hint = f' (write material: "{value}" to name a material called {value})' if isinstance(value, int) \
            and not isinstance(value, bool) else ""
        raise SceneError(source, f"{path}.material", f"expected a material name (a string), got {describe(value)}"
                                                     f"{hint}")


def _check_reference(source: str, path: str, material, defined: set[str]) -> None:
    """A shape's material names a defined one or indexes one (checked here, at
    the shape's own YAML path: boxes become quads before the scene sees them)."""
    if isinstance(material, str) and material not in defined:
        raise SceneError(source, f"{path}.material", unknown_material(material, defined))
    if isinstance(material, int) and material >= len(defined):
        raise SceneError(source, f"{path}.material", f"material index {material} is out of range "
                                                     f"(the scene has {len(defined)} materials)")


_MESH_KEYS = {"file", "material", "smooth", "transform"}
# trimesh's peak while loading, per byte of file: ~27 measured for a 19 MB
# binary PLY of 1M triangles (text formats hold fewer triangles per byte)
MESH_LOAD_BYTES_PER_FILE_BYTE = 32
# ... and per triangle a glTF's nodes instance (a 0.4 MB GLB placing one mesh
# 380 times is 7.8 M triangles): ~400 measured while trimesh builds and bakes them
MESH_LOAD_BYTES_PER_TRIANGLE = 512


def _meshes(source: str, docs, defined: set[str], memory: int | None = None, *, base: str | None = None) -> list[Mesh]:
    """Meshes read from files by trimesh, paths relative to the scene file.

    Every problem with a file names the scene file, the YAML path and the
    mesh file; degenerate faces are dropped with one warning counting them.
    The face limit is for the whole scene, so many meshes cannot add up to
    more than one may hold.  With a ``memory`` budget, a file too big to
    load within it is refused before it is read (:class:`MemoryBudgetError`).
    """
    if docs is None:
        return []
    if not isinstance(docs, list):
        raise SceneError(source, "meshes", f"expected a list, got {describe(docs)}")
    if base is None:
        base = "" if source.startswith("<") else os.path.dirname(source)
    meshes, total = [], 0
    for i, spec in enumerate(docs):
        path = f"meshes[{i}]"
        spec = _mapping(source, spec, path, _MESH_KEYS, {"file", "material"})
        _material_name(source, path, spec)
        try:  # what can be checked before the file is read, by the Mesh's own rules
            name = file_name(Mesh, spec["file"], "file")
            mesh_fields(Mesh, spec)
        except SceneError as e:
            raise e.within(source, path) from None
        file = os.path.join(base, name)
        data = _read_mesh_file(source, path, file, memory, mesh_files.MAX_MESH_FACES - total)
        total += data["faces"].shape[0]
        fields = {k: v for k, v in spec.items() if k != "file"}
        mesh = _build(source, path, Mesh, fields, vertices=data["vertices"], faces=data["faces"],
                      vertex_normals=data["vertex_normals"], uv=data["uv"], file=file, dropped=data["dropped"])
        if mesh.dropped:  # the file's, and slivers its transform rounds flat
            warnings.warn(SceneWarning(f"{source}: {path}.file: {file}: dropped {mesh.dropped} degenerate "
                                       "(zero-area) triangles"), stacklevel=3)
        _check_reference(source, path, mesh.material, defined)
        meshes.append(mesh)
    return meshes


_BOUNDARY_KEYS = {"sphere": ({"center", "radius", "transform"}, {"center", "radius"}),
                  "box": ({"min", "max", "transform"}, {"min", "max"}),
                  "mesh": ({"file", "transform"}, {"file"})}
_BOUNDARY_MATERIAL = 0  # a boundary is never shaded; its shape's material field is a placeholder


def _media(source: str, docs, memory: int | None = None, faces: int = 0, *, base: str | None = None) -> list[Medium]:
    """``media``: ``{boundary: {sphere | box | mesh: ...}, density, albedo}``
    each (see :mod:`wavefront.media`); a mesh boundary's file is read as a
    mesh's is, relative to the scene file, and must be closed.  ``faces``:
    the scene's mesh faces so far (the face limit is for the whole scene)."""
    if docs is None:
        return []
    if not isinstance(docs, list):
        raise SceneError(source, "media", f"expected a list, got {describe(docs)}")
    if base is None:
        base = "" if source.startswith("<") else os.path.dirname(source)
    media = []
    for i, spec in enumerate(docs):
        path = f"media[{i}]"
        spec = _mapping(source, spec, path, {"boundary", "density", "albedo"}, {"boundary", "density"})
        boundary_doc = _mapping(source, spec["boundary"], f"{path}.boundary", set(_BOUNDARY_KEYS))
        if len(boundary_doc) != 1:
            raise SceneError(source, f"{path}.boundary", "expected exactly one of: box, mesh, sphere, got "
                                                         f"{', '.join(sorted(boundary_doc)) or 'none'}")
        (kind, shape_doc), = boundary_doc.items()
        where = f"{path}.boundary.{kind}"
        allowed, required = _BOUNDARY_KEYS[kind]
        shape_doc = dict(_mapping(source, shape_doc, where, allowed, required))
        if kind == "sphere":
            boundary = _build(source, where, Sphere, shape_doc, material=_BOUNDARY_MATERIAL)
        elif kind == "box":
            boundary = _build(source, where, Box, shape_doc, material=_BOUNDARY_MATERIAL)
            try:
                box_faces(boundary, boundary, "")
            except SceneError as e:
                raise e.within(source, where) from None
        else:
            boundary = _boundary_mesh(source, where, shape_doc, base, memory, mesh_files.MAX_MESH_FACES - faces)
            faces += boundary.faces.shape[0]
        fields = {k: v for k, v in spec.items() if k != "boundary"}
        try:
            medium = Medium(boundary=boundary, **fields)
        except SceneError as e:
            rest = e.path.removeprefix(f"boundary.{kind}.") if e.path.startswith("boundary.") else e.path
            raise SceneError(source, join(where if e.path.startswith("boundary.") else path, rest),
                             e.problem) from None
        media.append(medium)
    return media


def _read_mesh_file(source: str, where: str, file: str, memory: int | None, max_faces: int) -> dict:
    """:func:`read_mesh` of a mesh or boundary at YAML path ``where``: with a
    ``memory`` budget, a file too big to load within it is refused before it
    is read (:class:`MemoryBudgetError`), by its size and by the triangles a
    glTF's instances declare; a problem names the scene file, ``where`` and the file."""
    if memory is not None:
        with contextlib.suppress(OSError):  # a missing file is read_mesh's to report
            refuse_unless_fits(memory, max(MESH_LOAD_BYTES_PER_FILE_BYTE * os.stat(file).st_size,
                                           MESH_LOAD_BYTES_PER_TRIANGLE * mesh_files.declared_triangles(file)),
                               f"{source}: {where}.file: loading {file}")
    def before_parse(triangles: int) -> None:  # an OBJ's polygons counted: many in a small file
        if memory is not None:
            refuse_unless_fits(memory, MESH_LOAD_BYTES_PER_TRIANGLE * triangles, f"{source}: {where}.file: loading {file}")

    try:
        return read_mesh(file, max_faces=max_faces, before_parse=before_parse)
    except MeshError as e:
        raise SceneError(source, f"{where}.file", f"{file}: {e}") from None


def _boundary_mesh(source: str, where: str, spec: dict, base: str, memory: int | None, max_faces: int) -> Mesh:
    """A medium's mesh boundary, read as :func:`_meshes` reads a mesh."""
    try:
        name = file_name(Mesh, spec["file"], "file")
        mesh_fields(Mesh, {"material": _BOUNDARY_MATERIAL, "transform": spec.get("transform")})
    except SceneError as e:
        raise e.within(source, where) from None
    file = os.path.join(base, name)
    data = _read_mesh_file(source, where, file, memory, max_faces)
    return _build(source, where, Mesh, {"transform": spec.get("transform")}, vertices=data["vertices"],
                  faces=data["faces"], material=_BOUNDARY_MATERIAL, file=file, dropped=data["dropped"])
