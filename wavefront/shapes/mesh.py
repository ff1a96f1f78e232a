"""Triangle meshes read from files by trimesh (OBJ, PLY, STL, glTF/GLB, OFF).

wavefront never parses mesh formats itself; it bounds what trimesh is given
(the file's size before a byte is read, the counts a PLY or OFF header
declares, the triangles the polygons of an OBJ, PLY or OFF make, a glTF's
instanced triangles, the number of faces after loading) and checks what
comes back (finite vertices, indices in range), so a hostile or broken file
is refused with one message instead of exhausting memory or crashing later.
"""

from __future__ import annotations

import io
import os
import re
import stat
from dataclasses import dataclass, field

import numpy as np

from ..geometry import MAX_COORDINATE, material_field
from ..transform import Transform, transform_field
from ..validation import describe, fail, first_line

# A 1M-triangle binary PLY is ~20 MB and as OBJ ~60 MB; 512 MiB leaves room
# for large models while refusing a 10 GB file before reading it.
MAX_MESH_BYTES = 512 * 1024 * 1024
# Faces per mesh: each costs ~0.5 KB once compiled with its BVH share, so
# 8 M faces is ~4 GB, the most a renderer on one workstation should attempt.
MAX_MESH_FACES = 8_000_000
# Formats trimesh reads that a scene may name, by file extension.
FORMATS = ("obj", "ply", "stl", "glb", "gltf", "off")


class MeshError(ValueError):
    """A mesh file cannot be used; the message is the problem only (the
    scene loader adds the scene file, the YAML path and the mesh file)."""


@dataclass(frozen=True, eq=False)
class Mesh:
    """A triangle mesh as loaded: object-space arrays, a material and a transform.

    ``vertices (V, 3)``, ``faces (F, 3)`` indices into them, optional
    ``vertex_normals (V, 3)`` (used when ``smooth``) and ``uv (V, 2)``.
    Compared by identity (NumPy arrays have no single truth value).
    """

    vertices: np.ndarray
    faces: np.ndarray
    material: str | int
    smooth: bool = False
    transform: Transform | None = None
    vertex_normals: np.ndarray | None = None
    uv: np.ndarray | None = None
    file: str = field(default="", metadata={"fingerprint": False})  # for messages; the arrays are hashed
    dropped: int = field(default=0)  # degenerate faces left out at load time

    def __post_init__(self):
        """The arrays' shapes and values are checked in bulk (one pass each)."""
        set_field = object.__setattr__
        vertices = _array(self, self.vertices, "vertices", np.float64, 3)
        if not (np.abs(vertices) <= MAX_COORDINATE).all():
            fail(self, "vertices", "has NaN, infinite or out-of-range coordinates")
        faces = _array(self, self.faces, "faces", np.int64, 3)
        if faces.shape[0] == 0:
            fail(self, "faces", "has no triangles")
        if faces.min() < 0 or faces.max() >= vertices.shape[0]:
            fail(self, "faces", f"has vertex indices out of range (there are {vertices.shape[0]} vertices)")
        set_field(self, "vertices", vertices)
        set_field(self, "faces", faces)
        for key, width in (("vertex_normals", 3), ("uv", 2)):
            value = getattr(self, key)
            if value is not None:
                value = _array(self, value, key, np.float64, width)
                if value.shape[0] != vertices.shape[0] or not np.isfinite(value).all():
                    fail(self, key, f"must be finite and have one row per vertex ({vertices.shape[0]})")
                set_field(self, key, value)
        for key, value in mesh_fields(self, {"material": self.material, "smooth": self.smooth,
                                             "transform": self.transform}).items():
            set_field(self, key, value)
        # every triangle where the ray tests will see it (which refuse a zero area)
        v, f = vertices.T if self.transform is None else self.transform.points(vertices.T), faces.T
        with np.errstate(over="ignore", invalid="ignore"):
            area2 = np.linalg.norm(np.cross(v[:, f[1]] - v[:, f[0]], v[:, f[2]] - v[:, f[0]], axis=0), axis=0)
        flat = area2 == 0
        if self.transform is not None and (not np.abs(v).max() <= MAX_COORDINATE or not np.isfinite(area2).all()
                                           or flat.all()):
            fail(self, "transform", "the transform takes triangles beyond floating-point range "
                                    "(non-finite, or flattened to zero area)")
        if flat.all():
            fail(self, "faces", "has only degenerate (zero-area) triangles")
        if flat.any():
            # a face with repeated or collinear corners (built in Python), or a sliver the
            # file holds (area 1e-17 of its size) that a rotation rounds to a line: dropped
            # and counted like a file's degenerate faces, not the whole mesh refused
            set_field(self, "faces", np.ascontiguousarray(faces[~flat]))
            set_field(self, "dropped", self.dropped + int(flat.sum()))

    def __len__(self) -> int:
        return self.faces.shape[0]

    @classmethod
    def read(cls, file, material: str | int, *, smooth: bool = False, transform: Transform | None = None,
             max_faces: int | None = None) -> Mesh:
        """A mesh from a file trimesh reads; ``dropped`` counts the degenerate
        faces left out.  Raises :class:`MeshError` (see :func:`read_mesh`)."""
        file = os.fspath(file)
        data = read_mesh(file, max_faces=max_faces)
        return cls(vertices=data["vertices"], faces=data["faces"], material=material, smooth=smooth,
                   transform=transform, vertex_normals=data["vertex_normals"], uv=data["uv"], file=file,
                   dropped=data["dropped"])


def mesh_fields(obj, spec: dict) -> dict:
    """A mesh's ``material``, ``smooth`` and ``transform`` checked (the scene
    loader checks them before reading the file)."""
    smooth = spec.get("smooth", False)
    if not isinstance(smooth, (bool, np.bool_)):
        fail(obj, "smooth", f"expected true or false, got {describe(smooth)}")
    return {"material": material_field(obj, spec["material"]), "smooth": bool(smooth),
            "transform": transform_field(obj, spec.get("transform"), "transform")}


def _array(obj, value, path: str, dtype, width: int) -> np.ndarray:
    """``value`` as a C-contiguous ``(N, width)`` array of ``dtype``, or a SceneError."""
    try:
        a = np.asarray(value)
        if a.dtype.kind not in ("f", "i", "u") or (np.dtype(dtype).kind == "i" and a.dtype.kind == "f"):
            raise ValueError
        a = np.ascontiguousarray(a, dtype=dtype)
    except (ValueError, TypeError, OverflowError):
        fail(obj, path, f"expected an array of numbers of shape (N, {width}), got {describe(value)}")
    if a.ndim != 2 or a.shape[1] != width:
        fail(obj, path, f"expected shape (N, {width}), got {a.shape}")
    return a


# numpy's code of each PLY type (trimesh's table)
_PLY_TYPES = {"char": "i1", "uchar": "u1", "int8": "i1", "uint8": "u1", "short": "i2", "ushort": "u2", "int16": "i2",
              "uint16": "u2", "int": "i4", "uint": "u4", "int32": "i4", "uint32": "u4", "float": "f4", "float32": "f4",
              "int64": "i8", "uint64": "u8", "float64": "f8", "double": "f8", "float16": "f2"}
# Lines of a PLY header trimesh acts on contain one of these (its other lines are comments).
_PLY_HEADER_WORDS = re.compile(rb"element|property|end_header")


def _ply_header(data: bytes, max_faces: int) -> tuple[dict, bool, bool, int] | None:
    """A PLY header as trimesh's ``_parse_header`` reads it: ``(elements,
    ascii, big_endian, body)``, elements ``{name: (count, {property: (type,
    None) or (count type, item type) for a list})}`` in its order, ``body``
    the offset after the header; None where trimesh refuses the header.

    Its rules, which the pre-count read otherwise (each a file whose faces
    it counted short, 0 of ~100,000 built): lines end at LF alone (readline);
    the second line is the format whatever it says; the header ends at the
    first line holding the word ``end_header`` (``comment xend_header`` is
    not one; a substring search ended it there) however far in (not only in
    the first 64 KiB); a line is an element when its first word contains
    ``element`` and a property when it contains ``property``; an element
    named again replaces the first but keeps its place (a dict); a count is
    Python's int() of its word (``+50``, ``5_0`` and other scripts' digits
    are counts).  Refused here, with the line and the word: a count int()
    does not read (``3.0``, ``3e0``: trimesh refuses the file too) and a
    negative count (trimesh takes it as a slice of the body's lines, which
    can step back over another element's); every count is held to the limit
    (a header may claim 10^12 faces over a body of a few bytes)."""
    first = data.find(b"\n")
    if first < 0 or b"ply" not in data[:first].lower():
        return None
    second = data.find(b"\n", first + 1)
    if second < 0:
        return None
    encoding = _header_text(data[first + 1:second]).strip().lower()
    elements, name, position = {}, None, second + 1
    for match in _PLY_HEADER_WORDS.finditer(data, position):
        if match.start() < position:
            continue  # on a line already read
        start = data.rfind(b"\n", 0, match.start()) + 1
        end = data.find(b"\n", match.start())
        end = len(data) if end < 0 else end
        position = end + 1
        words = _header_text(data[start:end]).split()
        if "end_header" in words:
            return elements, "ascii" in encoding, "big" in encoding, min(position, len(data))
        if not words:
            continue
        if "element" in words[0]:
            if len(words) != 3:
                return None
            name, text = words[1], words[2]
            # the line number only when refusing: counted for every element line, 150,000
            # empty elements took 112 s (quadratic)
            def where() -> str:
                line = data.count(b"\n", 0, start) + 1
                return f"the PLY header's count {text!r} of element {name!r} (line {line})"
            try:
                count = int(text)
            except ValueError:
                raise MeshError(f"{where()} is not a whole number") from None
            if count < 0:
                raise MeshError(f"{where()} is negative")
            if count > 3 * max_faces:
                raise MeshError(f"declares {count} {name} elements; the limit is {3 * max_faces}")
            elements[name] = (count, {})
        elif "property" in words[0]:
            if not elements or len(words) < 2:
                return None
            if len(words) == 3:
                if words[1] not in _PLY_TYPES:
                    return None
                elements[name][1][words[2]] = (words[1], None)
            elif "list" in words[1]:
                if len(words) != 5 or words[2] not in _PLY_TYPES or words[3] not in _PLY_TYPES:
                    return None
                elements[name][1][words[4]] = (words[2], words[3])
    return None  # no end_header: trimesh reads past the end and refuses it


def _header_text(line: bytes) -> str:
    """A header line as trimesh decodes it (UTF-8; :func:`_text_as_utf8` gives
    it a Latin-1 header as UTF-8)."""
    try:
        return line.decode("utf-8")
    except UnicodeDecodeError:
        return line.decode("latin-1")


def _ply_triangle_bound(data: bytes, max_faces: int) -> int:
    """At least the triangles trimesh makes of a PLY's ``face`` element, from
    its header (:func:`_ply_header`) and the list counts in its body, before
    trimesh parses it.

    trimesh turns an n-gon into n - 2 triangles.  A binary file's lists all
    have the first face's length (trimesh reads that one and assumes it for
    every face), so the bound is exact: the faces the body holds times n - 2.
    An ASCII file's face lines are read one by one (:func:`_line_polygons`),
    the values before the index list (a flag, a uv list) stepped over."""
    end = _ply_header_end(data)
    if end is not None and not data[:end].isascii():
        # trimesh is given the header decoded whole (Latin-1 if any line is not UTF-8): a line
        # 'end_header\xc2\xa0' then ends nothing; read line by line it ended the header (0 of 399,600)
        data = _text_as_utf8(data, "ply")
    header = _ply_header(data, max_faces)
    if header is None:
        return 0
    elements, ascii_body, big, body = header
    if "face" not in elements or not elements["face"][0]:
        return 0
    count, properties = elements["face"]
    names = list(properties)
    if ascii_body:  # trimesh takes vertex_index, else vertex_indices
        indices = next((n for n in ("vertex_index", "vertex_indices") if n in properties), None)
    else:  # the one property, else the first of those names
        indices = names[0] if len(names) == 1 else next(
            (n for n in names if n in ("vertex_index", "vertex_indices")), None)
    if indices is None or properties[indices][1] is None:
        return 0  # trimesh finds no faces, or refuses them
    if ascii_body:
        in_order = list(elements)
        skip = sum(elements[name][0] for name in in_order[:in_order.index("face")])
        if not data.isascii():  # trimesh splits the body's text at U+2028, U+2029 and NEL too
            data = data[:body] + _split_as_str(data[body:], blanks=False)
        before = tuple(properties[n][1] is not None for n in names[:names.index(indices)])
        lists = sum(item is not None for _, item in properties.values())
        return _line_polygons(data, body, skip, count, blank_lines_count=True, before=before,
                              first_applies=lists <= 1)
    order = ">" if big else "<"
    position = body
    for name, (element_count, element_properties) in elements.items():  # walk the elements as trimesh does
        size = 0
        for key, (scalar, item) in element_properties.items():
            if item is None:
                size += int(_PLY_TYPES[scalar][1])
                continue
            count_type = np.dtype(order + _PLY_TYPES[scalar])
            raw = data[position + size:position + size + count_type.itemsize]
            if count_type.kind == "f" or len(raw) < count_type.itemsize:
                return 0  # trimesh cannot read it either
            length = int(np.frombuffer(raw, dtype=count_type)[0])
            if name == "face" and key == indices:
                polygon = length
            size += count_type.itemsize + max(length, 0) * int(_PLY_TYPES[item][1])
        if name == "face":
            held = (len(data) - position) // size if size > 0 else 0
            return min(count, held) * max(polygon - 2, 0)
        position += element_count * size
    return 0


def _off_triangle_bound(data: bytes, max_faces: int) -> int:
    """At least the triangles trimesh makes of an OFF's faces (an n-gon is
    n - 2), after holding the header's counts to the limit.

    Read as trimesh reads it: its ``comment_strip`` first removes each ``#``
    up to the next LF (not to a lone CR or another str.splitlines break:
    lines a comment runs over that way are gone before the lines are split;
    read as lines, they were taken for the counts, vertices and faces, and
    the real faces after them counted nothing), and repeats the lines before
    the first comment but the first."""
    data = _text_as_utf8(data, "off")  # as trimesh gets it: a Latin-1 0x85 byte is NEL, a line break
    if b"#" in data:  # a copy, only for a file with a comment; freed before trimesh parses
        first = data.find(b"#")
        head = data[:first]
        # comment_strip also repeats the text before the first comment from its
        # second line on (its first chunk is both its lead and a comment's
        # remainder): those lines are read twice, shifting the faces after them.
        repeated = head[head.find(b"\n") + 1:] if b"\n" in head else b""
        data = head + (b"\n" + repeated if repeated else b"") + _OFF_COMMENT.sub(b"", data[first:])
    data = _split_as_str(data, blanks=True)
    # trimesh splits at the first OFF of the text, comments gone (above), however far in: looked
    # for in the first 64 KiB only, 100 KB of blank lines before it or after it counted 0 of 99,900
    at = data.find(b"OFF")
    if at < 0:
        return 0  # trimesh refuses it
    content = _CONTENT.search(data, at + 3)  # the first line with content: the counts
    if content is None:
        return 0  # trimesh refuses it
    line_end = _NEXT_LINE_BREAK.search(data, content.start())
    line_end = len(data) if line_end is None else line_end.start()
    counts, position = data[content.start():line_end].split(), line_end + 1
    if counts is None or len(counts) < 2:
        return 0  # trimesh refuses it ("a malformed vertex/face count line")
    vertices, faces = _off_counts(counts)
    for what, count in (("vertices", vertices), ("faces", faces)):
        if count > 3 * max_faces:
            raise MeshError(f"declares {count} {what}; the limit is {3 * max_faces}")
    return _line_polygons(data, position, vertices, faces, blank_lines_count=False)


_OFF_COUNT_NAMES = ("vertex count", "face count", "edge count")


def _off_counts(words: list[bytes]) -> tuple[int, int]:
    """The vertex and face counts of an OFF's count line, read as trimesh
    reads them: ``np.array(words, dtype=np.int64)``, which is Python's int()
    of each word, so ``+3``, ``3_0``, ``03`` and other scripts' digits
    (Arabic-Indic, fullwidth) are counts; ``3.0`` or ``3e0`` are not, and
    trimesh refuses the file.  Read as ASCII digits only, the first forms
    counted 0 triangles of a mesh trimesh then loaded whole.

    Refused here with the word: a word int() does not read or int64 does not
    hold (trimesh refuses those too), and a negative vertex or face count,
    which trimesh takes as a slice from the end of the file's lines (a face
    count of -7 over 4 vertices and 50 quads loaded 96 triangles)."""
    numbers = []
    for i, word in enumerate(words):
        name = _OFF_COUNT_NAMES[i] if i < len(_OFF_COUNT_NAMES) else f"count {i + 1}"
        text = word.decode("utf-8", errors="replace")
        try:
            number = int(text)
        except ValueError:
            raise MeshError(f"the OFF header's {name} {text!r} is not a whole number") from None
        if not -2**63 <= number < 2**63:
            raise MeshError(f"the OFF header's {name} {text!r} is out of range")
        if number < 0 and i < 2:
            raise MeshError(f"the OFF header's {name} {text!r} is negative")
        numbers.append(number)
    return numbers[0], numbers[1]


# A byte other than a blank or a line break (once _split_as_str has made the others of str.split
# a space or a vertical tab).
_CONTENT = re.compile(rb"[^ \t\n\r\v\f\x1c-\x1f]")
# trimesh's comment_strip: a '#' to the next LF (only) is gone, the LF stays.
_OFF_COMMENT = re.compile(rb"#[^\n]*")
_LINE_CHUNK = 1 << 22  # bytes of lines scanned at once: temporaries of a few times this, whatever the file's size
_BLANK = np.zeros(256, dtype=bool)
_BLANK[list(b" \t\x1f")] = True  # what str.strip() and str.split() take for blanks in one byte (\x1f too)
_EMPTY = np.zeros(256, dtype=bool)
_EMPTY[list(b"\r\n#")] = True
# Leading blanks skipped a byte at a time for every line of a chunk at once:
# fixed-width columns (%10d) need ten; each further blank costs a pass over
# a chunk's lines, stopped early once no line has one.  The lines with more
# (rare) are then scanned alone (_first_other_than_blank).
_LEADING_BLANKS = 64
_COUNT_DIGITS = 12  # more than the tokens any line of a 512 MiB file holds

# Bytes that end a line as str.splitlines reads it, with which trimesh splits a
# PLY's ASCII body and an OFF: a lone CR (old Mac files) as well as LF (a CR
# before an LF is not a break of its own: the pair is one); form feed, vertical
# tab and the ASCII separators too.  Split at LF alone, a CR-only OFF counted
# no triangles at all.
_LINE_BREAK = np.zeros(256, dtype=bool)
_LINE_BREAK[list(b"\n\r\v\f\x1c\x1d\x1e")] = True
_NEXT_LINE_BREAK = re.compile(rb"\r(?!\n)|[\n\v\f\x1c-\x1e]")


# Characters str.strip() and str.split() take for blanks that the byte scan
# does not know: \x1f and, in UTF-8, NBSP, U+1680, U+2000-U+200A, U+202F,
# U+205F, U+3000.  A line of them alone is blank to trimesh (an OFF drops it):
# taken for content, each shifted every later line (a face read as a vertex).
_UNICODE_BLANK = re.compile(rb"\xc2\xa0|\xe1\x9a\x80|\xe2\x80[\x80-\x8a\xaf]|\xe2\x81\x9f|\xe3\x80\x80")


# Line breaks of str.splitlines (with which trimesh splits an OFF and a PLY's
# ASCII body) outside ASCII, in UTF-8: NEL, U+2028, U+2029.  Unseen, a file
# whose lines end so was one line: 0 triangles counted.
_UNICODE_BREAK = re.compile(rb"\xc2\x85|\xe2\x80[\xa8\xa9]")


def _split_as_str(data: bytes, *, blanks: bool) -> bytes:
    """``data`` with str.splitlines' line breaks outside ASCII made one the
    scan knows, and the characters str.strip() and str.split() see as blanks
    (``blanks``) made plain spaces, so the byte scan splits its lines and
    words as trimesh does; ``data`` itself (no copy) when it has none."""
    if blanks and b"\x1f" in data:
        data = data.replace(b"\x1f", b" ")
    if data.isascii():
        return data
    # a break of one byte the scan knows; not LF, which would join a CR before it into one break
    data = _UNICODE_BREAK.sub(b"\v", data)
    if blanks:
        data = _UNICODE_BLANK.sub(b" ", data)  # shorter lines: what a line can list is still held to its length
    return data


def _only_newlines(data: bytes, start: int) -> bool:
    """Whether every line of ``data`` from ``start`` ends in LF (or CRLF): then
    a comparison finds them, ~2x faster than the table (a few C scans to know,
    ~0.5 ms each for 11 MiB, and two counts when the file has a CR at all)."""
    if data.find(b"\r", start) >= 0 and data.count(b"\r", start) != data.count(b"\r\n", start):
        return False
    return not any(data.find(bytes([b]), start) >= 0 for b in b"\v\f\x1c\x1d\x1e")


def _line_breaks(a: np.ndarray, low: int, high: int, only_newlines: bool) -> np.ndarray:
    """Positions in ``[low, high)`` of the bytes ``a`` that end a line (see ``_LINE_BREAK``)."""
    if only_newlines:
        return np.flatnonzero(a[low:high] == ord("\n")) + low
    breaks = _LINE_BREAK[a[low:high]]
    cr = np.flatnonzero(a[low:high] == ord("\r"))
    if cr.size:
        after = np.minimum(cr + low + 1, a.size - 1)
        breaks[cr[(cr + low + 1 < a.size) & (a[after] == ord("\n"))]] = False
    return np.flatnonzero(breaks) + low


def _first_other_than_blank(a: np.ndarray, lead: np.ndarray, ends: np.ndarray) -> np.ndarray:
    """For lines from ``lead`` to ``ends`` (sorted), the position of each one's
    first byte other than a blank, or its end: one pass over their span, so
    a blank line is blank however long (trimesh drops an OFF's blank lines;
    taken for content, one shifted every face line after it)."""
    low, high = int(lead[0]), int(ends[-1])
    others = np.flatnonzero(~_BLANK[a[low:high]]) + low
    at = np.searchsorted(others, lead)
    found = at < others.size  # else blank to the span's end
    first = ends.copy()
    first[found] = np.minimum(others[at[found]], ends[found])
    return first


def _line_polygons(data: bytes, start: int, skip: int, count: int, *, blank_lines_count: bool,
                   before: tuple[bool, ...] = (), first_applies: bool = False) -> int:
    """At least the triangles trimesh makes of ``count`` polygon lines
    ``n i1 ... in`` (a PLY face or an OFF face) after ``skip`` lines from
    byte ``start``: the sum of n - 2, with n held to what the line can list
    after its count (a count of 10^9 on a short line gives what the line
    lists).  ``before``: the values of a PLY face before its index list, a
    scalar (False) or a list (True) each, whose count is read to step over
    it.  Blank and comment lines are not counted unless ``blank_lines_count``
    (PLY reads every line; OFF skips them).  Scanned with NumPy in chunks,
    never per line in Python.

    A count is read as a whole number of ASCII digits, after an optional
    ``+`` (and with ``_`` between digits: Python's int() reads an OFF's
    ``4_0`` as 40; NumPy's float parse refuses it in a PLY, so trimesh loads
    nothing).  Any other count (negative, ``4.0``, ``4e1``, other scripts'
    digits) counts all the line lists after it: trimesh reads ``-2`` as the
    slice ``[1:-1]`` (every value but the last, a fan of 1996 triangles from a
    line of 2000 indices), a PLY's ``4e1`` as 40 and an OFF's Arabic-Indic
    digits by int().  Read as counting nothing, each of them was a mesh
    trimesh built whole with 0 triangles counted.  Valid files write plain
    digits, for which this is exact.

    ``first_applies`` (a PLY face with one list at most): trimesh applies
    the first line's count to every line when they all hold as many values
    (a first line of 2000 indices made every later ``3 ...`` line of as
    many a 1998-triangle fan: 2,047 counted of 99,900 built), so the lines'
    values are counted when their counts differ, and if they are all as
    many, each line counts the larger of its own count and the first's."""
    a = np.frombuffer(data, dtype=np.uint8)
    n = a.size
    seen = total = 0
    chunk_start = start
    first = None  # the first face line's count and values, once read (first_applies)
    same_width, as_first = True, 0  # whether every line has the first's values so far; the total if so
    only_newlines = _only_newlines(data, start)
    while chunk_start < n and seen < skip + count:
        chunk_end = min(chunk_start + _LINE_CHUNK, n)
        # lines starting in this chunk: at its first byte if a line starts there, and after each line break
        starts = _line_breaks(a, chunk_start - 1, chunk_end - 1, only_newlines) + 1 if chunk_start > start \
            else np.concatenate(([start], _line_breaks(a, start, chunk_end - 1, only_newlines) + 1))
        chunk_start = chunk_end
        if not starts.size:
            continue
        if only_newlines:
            following = data.find(b"\n", int(starts[-1]))
        else:
            following = _NEXT_LINE_BREAK.search(data, int(starts[-1]))
            following = following.start() if following else -1
        ends = np.append(starts[1:] - 1, following if following >= 0 else n)  # each line's break
        lead = starts.copy()  # the first byte after up to _LEADING_BLANKS blanks
        for _ in range(_LEADING_BLANKS):
            step = (lead < ends) & _BLANK[a[np.minimum(lead, n - 1)]]
            if not step.any():
                break
            lead += step
        deep = np.flatnonzero((lead < ends) & _BLANK[a[np.minimum(lead, n - 1)]])
        if deep.size:  # lines of more than _LEADING_BLANKS blanks (rare): found for those alone
            lead[deep] = _first_other_than_blank(a, lead[deep], ends[deep])
        # lead is now each line's first byte other than a blank (or its end)
        if not blank_lines_count:
            content = (lead < ends) & ~_EMPTY[a[np.minimum(lead, n - 1)]]
            starts, ends, lead = starts[content], ends[content], lead[content]
        index = np.arange(seen, seen + starts.size)
        seen += starts.size
        mine = (index >= skip) & (index < skip + count)
        if not mine.any():
            continue
        ends, lead = ends[mine], lead[mine]
        at, stepped = _count_positions(a, lead, ends, before) if before else (lead, np.ones(lead.size, dtype=bool))
        value, exact = _read_counts(a, at, ends)
        exact &= stepped
        value = np.where(exact, value, _UNREAD)
        # values the line can list after its count (one character and one blank each); a line
        # whose earlier lists could not be stepped over: every value it holds
        room = np.where(stepped, (ends - at + 1) // 2 - 1, (ends - lead + 1) // 2)
        total += int(np.maximum(np.minimum(value, room) - 2, 0).sum())
        if first_applies:
            if first is None:
                first, width = int(value[0]), int(_counts_between(a, lead[:1], ends[:1], _SEPARATOR)[0])
            if same_width and (value != first).any():  # else both ways count the same: no need to know
                same_width = bool((_counts_between(a, lead, ends, _SEPARATOR) == width).all())
            if same_width:
                as_first += int(np.maximum(np.minimum(np.maximum(value, first), room) - 2, 0).sum())
    return as_first if first_applies and same_width else total


_UNREAD = np.int64(1) << 62  # a count not read: the line lists all it can
# Bytes that end a value: blanks, and a CR (kept at a CRLF line's end).
_VALUE_END = _BLANK.copy()
_VALUE_END[ord("\r")] = True
_SEPARATOR = _VALUE_END | _LINE_BREAK


def _read_counts(a: np.ndarray, at: np.ndarray, ends: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The whole numbers starting at ``at`` (each before its line's end
    ``ends``), and whether each was read: ASCII digits after an optional
    ``+``, ``_`` allowed between them, ending at a blank or the line's end
    (see :func:`_line_polygons`).  At most ``_COUNT_DIGITS`` digits."""
    n = a.size
    position = at + ((at < ends) & (a[np.minimum(at, n - 1)] == ord("+")))
    value = np.zeros(at.size, dtype=np.int64)
    digits = np.zeros(at.size, dtype=np.int64)
    used = np.zeros(at.size, dtype=np.int64)
    going = np.ones(at.size, dtype=bool)
    for k in range(2 * _COUNT_DIGITS):
        inside = position + k < ends
        byte = a[np.minimum(position + k, n - 1)]
        digit = inside & (byte >= ord("0")) & (byte <= ord("9"))
        going &= (digit & (digits < _COUNT_DIGITS)) | (inside & (byte == ord("_")) & (digits > 0))
        if not going.any():
            break
        value = np.where(going & digit, value * 10 + (byte.astype(np.int64) - ord("0")), value)
        digits += going & digit
        used += going
    stop = position + used
    read = (digits > 0) & ((stop >= ends) | _VALUE_END[a[np.minimum(stop, n - 1)]])
    return value, read


def _count_positions(a: np.ndarray, lead: np.ndarray, ends: np.ndarray,
                     before: tuple[bool, ...]) -> tuple[np.ndarray, np.ndarray]:
    """Where each line's count is, after the values ``before`` it (a scalar
    or a list, whose count is read to step over it), and whether each line
    could be stepped through (a list's count not read: False).  A line with
    fewer values gives its end.  From the positions of every value of the
    lines' span (a few times its bytes, as the other temporaries)."""
    low, high = int(lead[0]), int(ends[-1])
    separator = _SEPARATOR[a[low:high]]
    first = ~separator
    first[1:] &= separator[:-1]  # a value starts after a separator (or where the span does)
    del separator
    values = np.flatnonzero(first) + low
    del first
    ok = np.ones(lead.size, dtype=bool)
    if not values.size:
        return ends.copy(), ok
    t = np.searchsorted(values, lead)
    last = np.searchsorted(values, ends)  # each line's values are values[t:last]
    for is_list in before:
        if is_list:
            length, read = _read_counts(a, values[np.minimum(t, values.size - 1)], ends)
            ok &= read | (t >= last)
            t = t + 1 + np.where(read, length, 0)
        else:
            t = t + 1
    t = np.minimum(t, last)
    return np.where(t < last, values[np.minimum(t, values.size - 1)], ends), ok


def read_mesh(path: str, *, max_bytes: int | None = None, max_faces: int | None = None,
              before_parse=None) -> dict:
    """Read a mesh file into plain arrays, bounded and checked.

    ``before_parse(triangles)``, if given, is called with an upper bound of
    the triangles an OBJ's polygons make, once its bytes are read and before
    trimesh parses them (the caller's memory check: one line of a 4 MB OBJ
    listing a million vertices is a million triangles, far more than the
    file's size suggests).

    Returns
    -------
    dict with ``vertices (V, 3)`` float64, ``faces (F, 3)`` int64, ``vertex_normals
    (V, 3)`` or None, ``uv (V, 2)`` or None, and ``dropped``, the number of
    degenerate (zero-area) faces left out.

    Raises
    ------
    MeshError
    """
    import trimesh  # the standard Python mesh reader; imported only when a scene has meshes

    max_bytes = MAX_MESH_BYTES if max_bytes is None else max_bytes
    max_faces = MAX_MESH_FACES if max_faces is None else max_faces
    ext = os.path.splitext(path)[1].lower().lstrip(".")
    if ext not in FORMATS:
        raise MeshError(f"unknown mesh format {ext!r} (expected one of: {', '.join(FORMATS)})")
    try:
        info = os.stat(path)
        if not stat.S_ISREG(info.st_mode):  # a device or pipe (/dev/zero) would stream until the limit
            raise MeshError("not a regular file")
        size = info.st_size
        if size > max_bytes:
            raise MeshError(f"file is {size} bytes; the limit is {max_bytes}")
        with open(path, "rb") as f:
            data = f.read(max_bytes + 1)  # a file growing after the stat is still bounded
    except OSError as e:
        raise MeshError(f"cannot read: {e.strerror or e}") from None
    except MeshError:
        raise
    except ValueError:  # os.stat of a name holding a NUL byte (Mesh.read; the scene loader refuses it first)
        raise MeshError("cannot read: a file name cannot hold a NUL byte") from None
    if len(data) > max_bytes:
        raise MeshError(f"file is more than {max_bytes} bytes")
    if not data.strip():
        raise MeshError("the file is empty")
    if ext in ("ply", "off"):  # polygon lists counted before trimesh builds their triangles
        triangles = (_ply_triangle_bound if ext == "ply" else _off_triangle_bound)(data, max_faces)
        if triangles > max_faces:
            raise MeshError(f"its polygons make {triangles} triangles; the limit is {max_faces}")
        if before_parse is not None:
            before_parse(triangles)
    elif ext == "obj":  # counted before trimesh builds them
        triangles = _obj_triangle_bound(data)
        if triangles > max_faces:
            raise MeshError(f"has more than {max_faces} faces; the limit is {max_faces}")
        line = _obj_zero_index_line(data)
        if line is not None:
            raise MeshError(f"line {line}: a face has index 0 (OBJ's vertex, uv and normal indices start at 1; "
                            "negative ones count back from the last)")
        if before_parse is not None:
            before_parse(triangles)
    options = {}
    if ext in ("glb", "gltf"):  # instances multiply a small file's triangles: counted before trimesh builds them
        doc = _gltf_document(data, ext)
        _gltf_references(doc)
        declared = _gltf_triangles(doc)
        if declared > max_faces:
            raise MeshError(f"declares {declared} triangles (meshes and their instances); the limit is {max_faces}")
        data = _without_images(data, doc, ext)
        options["resolver"] = _gltf_files(doc, os.path.dirname(path), max_bytes - len(data))
    data = _text_as_utf8(data, ext)
    try:
        # load_scene and baking each instance here, not trimesh.load(force="mesh"): that
        # concatenation drops the normals a file stores (smooth: true must use them).
        # trimesh's arithmetic on hostile numbers (normals of 1e300 coordinates) only
        # warns; what it returns is checked below, and its warnings would be extra lines.
        with np.errstate(all="ignore"):
            scene = trimesh.load_scene(io.BytesIO(data), file_type=ext, process=False, **options)
            del data
            vertices, faces, normals, uv = _baked(scene, max_faces)
    except MeshError:
        raise
    except MemoryError:
        raise MeshError("too large to load") from None
    except Exception as e:  # trimesh reports malformed files with many exception types
        out_of_range = re.fullmatch(r"index (-?\d+) is out of bounds for axis 0 with size (\d+)", str(e))
        if ext == "obj" and isinstance(e, IndexError) and out_of_range:  # trimesh's vertex index, less one if > 0
            index, size = int(out_of_range[1]), out_of_range[2]
            # trimesh clamps an index past int64 to its maximum: not the file's number, so not quoted
            which = f"index {index + 1 if index >= 0 else index}" if abs(index) < 2**62 else "an index"
            raise MeshError(f"a face has {which}, out of range (it has {size} vertices)") from None
        raise MeshError(f"cannot be read as {ext.upper()}: {_reader_problem(e)}") from None
    if faces.shape[0] == 0:
        raise MeshError("has no triangles")
    if not np.isfinite(vertices).all():
        raise MeshError("has NaN or infinite vertex coordinates")
    if vertices.size and not np.abs(vertices).max() <= MAX_COORDINATE:
        raise MeshError(f"has vertex coordinates beyond ±{MAX_COORDINATE:g}")
    if faces.min() < 0 or faces.max() >= vertices.shape[0]:
        raise MeshError(f"has face indices out of range (it has {vertices.shape[0]} vertices)")
    if normals is not None and not np.isfinite(normals).all():
        normals = None
    if uv is not None and not np.isfinite(uv).all():
        uv = None
    v = vertices.T
    with np.errstate(over="ignore", invalid="ignore"):  # an edge's square may overflow: its face is kept
        area2 = np.linalg.norm(np.cross(v[:, faces[:, 1]] - v[:, faces[:, 0]], v[:, faces[:, 2]] - v[:, faces[:, 0]],
                                        axis=0), axis=0)
    keep = ~(area2 == 0)  # NaN: overflowed, so not degenerate
    dropped = int(faces.shape[0] - keep.sum())
    if dropped == faces.shape[0]:
        raise MeshError("has only degenerate (zero-area) triangles")
    return dict(vertices=vertices, faces=faces[keep] if dropped else faces, vertex_normals=normals, uv=uv,
                dropped=dropped)


def _reader_problem(e: Exception) -> str:
    """What trimesh's exception says, as the end of one line: a bare KeyError
    ("'uri'") or AttributeError from a glTF's JSON said nothing of the file."""
    text = first_line(e) if str(e).strip() else ""
    if isinstance(e, KeyError):
        return f"a required entry {text} is missing"
    if isinstance(e, (AttributeError, TypeError)):
        return f"an entry has the wrong type ({text})"
    if isinstance(e, (AssertionError, IndexError)) or not text:
        return f"malformed ({type(e).__name__}{': ' + text if text else ''})"
    return text


def _obj_triangle_bound(data: bytes) -> int:
    """At least the triangles trimesh makes of an OBJ's faces, counted per
    face line with NumPy in chunks, never per line in Python.

    Read as trimesh reads them: lines end at LF (CRLF made LF first) and a
    backslash before one continues the line (joined in a copy, only then); a
    face line starts ``f``; its vertices are its words, split at any
    whitespace str.split knows (a vertical tab, form feed, lone CR, \\x1c-
    \\x1f, NBSP, U+3000, ...: a count of spaces and tabs alone counted 2
    triangles of a 1998-triangle fan whose indices a vertical tab parted).
    An n-word line is n - 2 triangles, except that where every face line of
    a chunk has as many values (words split at ``/`` too), trimesh gives
    each the first line's words: so the count is exact when every face line
    has the same number of values per word (``1 2 3`` or ``1/1/1 2/2/2 ...``
    throughout, as exporters write), and otherwise each line counts at least
    the smaller of its values and the most words a face line has."""
    # as trimesh gets it: a Latin-1 file's bare 0xA0 and 0x85 bytes are NBSP and NEL, which
    # str.split() splits at (read as bytes, 2 of 2001 triangles counted); no copy for ASCII
    data = _text_as_utf8(data, "obj")
    if b"\\\n" in data or b"\\\r\n" in data:  # a copy, only for such a file
        data = data.replace(b"\r\n", b"\n").replace(b"\\\n", b"")
    data = _split_as_str(data, blanks=True)
    # trimesh strips the text first: its first line starts at the first byte kept (' f 1 2 3 4 5'
    # first in the file is a face: counted from byte 0, 0 of 3 triangles)
    content = _CONTENT.search(data)
    begin = content.start() if content else len(data)
    total, regular, most = _obj_face_triangles(data, begin=begin)
    return total if regular else _obj_face_triangles(data, most, begin=begin)[0]


# Bytes that part an OBJ face's words (str.split's whitespace once _split_as_str has made the
# rest of it a space or a vertical tab), and its values (a '/' too).
_OBJ_WORD_END = np.zeros(256, dtype=bool)
_OBJ_WORD_END[list(b" \t\n\r\v\f\x1c\x1d\x1e\x1f")] = True
_OBJ_VALUE_END = _OBJ_WORD_END.copy()
_OBJ_VALUE_END[ord("/")] = True


def _obj_face_triangles(data: bytes, most: int | None = None, *, begin: int = 0) -> tuple[int, bool, int]:
    """Triangles of the face lines of ``data`` (see :func:`_obj_triangle_bound`):
    ``(total, regular, most words of a line)``, ``regular`` when every face
    line has as many values per word as the first.  Without ``most`` each
    line counts max(words - 2, 0); with it, max(words, min(values, most)) - 2.
    The first line starts at ``begin`` (the text's first byte str.strip() keeps)."""
    a = np.frombuffer(data, dtype=np.uint8)
    n = a.size
    total, per_word, regular, most_words = 0, None, True, 0
    chunk_start = begin
    while chunk_start < n:
        chunk_end = min(chunk_start + _LINE_CHUNK, n)
        starts = np.flatnonzero(a[max(chunk_start - 1, 0):chunk_end - 1] == ord("\n")) + max(chunk_start - 1, 0) + 1
        if chunk_start == begin and not (starts.size and starts[0] == begin):
            starts = np.concatenate(([begin], starts))
        chunk_start = chunk_end
        starts = starts[a[np.minimum(starts, n - 1)] == ord("f")] if starts.size else starts
        starts = starts[starts < n]
        if not starts.size:
            continue
        following = data.find(b"\n", int(starts[-1]))
        ends = np.minimum(np.append(np.flatnonzero(a[int(starts[0]):int(starts[-1])] == ord("\n"))
                                    + int(starts[0]), following if following >= 0 else n), n)
        # each face line's end: the first LF after its start
        ends = ends[np.searchsorted(ends, starts)]
        lead = starts + 1  # after the 'f'
        words = _counts_between(a, lead, ends, _OBJ_WORD_END)
        values = _counts_between(a, lead, ends, _OBJ_VALUE_END)
        most_words = max(most_words, int(words.max()))
        if most is None:
            if per_word is None and words[0] > 0:
                per_word = (int(values[0]), int(words[0]))
            if per_word is not None:
                regular &= bool((values * per_word[1] == words * per_word[0]).all())
            total += int(np.maximum(words - 2, 0).sum())
        else:
            total += int(np.maximum(np.maximum(words, np.minimum(values, most)) - 2, 0).sum())
    return total, regular, most_words


def _counts_between(a: np.ndarray, lead: np.ndarray, ends: np.ndarray, end_table: np.ndarray) -> np.ndarray:
    """The number of runs of bytes not in ``end_table`` on each line from
    ``lead`` to ``ends`` (sorted, apart), one starting at ``lead`` itself too:
    an OBJ face's words and values, a PLY or OFF line's values (``_SEPARATOR``;
    there each ``lead`` is a line's first byte other than a blank)."""
    low, high = int(lead[0]), int(ends[-1])
    if high <= low:
        return np.zeros(lead.size, dtype=np.int64)
    parting = end_table[a[low:high]]
    first = ~parting
    first[1:] &= parting[:-1]
    inside = lead < high
    first[lead[inside] - low] = ~parting[lead[inside] - low]  # a word right after the 'f' (a line 'f\\' continued)
    del parting
    starts = np.flatnonzero(first) + low
    del first
    return np.searchsorted(starts, ends) - np.searchsorted(starts, lead)


# Bytes a zero index may follow / be followed by in a face line ("f 0 2 3", "f 1/0/1 ...", "f -0 ...").
_BEFORE_INDEX = np.zeros(256, dtype=bool)
_BEFORE_INDEX[list(b" \t/\v\f\r\x1c\x1d\x1e\x1f")] = True  # the whitespace that parts trimesh's words too
_SIGN = np.zeros(256, dtype=bool)
_SIGN[list(b"+-")] = True
_AFTER_INDEX = np.zeros(256, dtype=bool)
_AFTER_INDEX[list(b" \t/\r\n#\v\f\x1c\x1d\x1e\x1f")] = True
_ZERO_INDEX_CHUNK = 1 << 22  # bytes scanned at once: temporaries of a few times this, whatever the file's size
_NOT_ZERO = re.compile(rb"[^0]")


def _obj_zero_index_line(data: bytes) -> int | None:
    """The line number of the first face line with an index of 0, else None.

    OBJ indices start at 1 (negative ones count back from the end), so 0 is
    invalid; trimesh silently reads it as vertex 1 (or as the first uv or
    normal), which turns a broken face into a wrong or degenerate one.  A
    zero index is a run of ``0`` (optionally signed) between separators, on
    a line starting ``f``, outside a ``#`` comment.  Found with NumPy over
    chunks of the bytes, never per line in Python: a Python regex over
    every face line took a third of trimesh's own parsing time.

    A line ending in a backslash goes on on the next: trimesh turns CRLF
    into LF and then takes out every backslash-newline before it reads a
    line, so a file holding one is scanned so joined (a copy, only then),
    and the line given is still the file's own.  It strips the text first
    and then ends it with an LF, so a backslash last before trailing blanks
    continues into that LF: the last line ends there, as if unbroken."""
    end = _last_other_than_stripped(data)
    if end >= 0 and data[end] == ord("\\"):
        data = data[:end]  # a copy, only for such a file (the line numbers are unchanged: a prefix)
    if b"\\\n" not in data and b"\\\r\n" not in data:
        offset = _obj_zero_index_offset(data)
        return None if offset is None else data.count(b"\n", 0, offset) + 1
    text = data.replace(b"\r\n", b"\n")
    joined = text.replace(b"\\\n", b"")
    offset = _obj_zero_index_offset(joined)
    if offset is None:
        return None
    # The continuations before that byte, r, each took out a newline: the least r with
    # r >= text.count(continuations, 0, offset + 2 r + 2) (one more can start in each
    # further two bytes, so the test is monotonic).  A search of C counts: never a
    # Python loop over a hostile file's millions of continuations.
    low, high = 0, text.count(b"\\\n")
    while low < high:
        middle = (low + high) // 2
        if text.count(b"\\\n", 0, offset + 2 * middle + 2) <= middle:
            high = middle
        else:
            low = middle + 1
    return joined.count(b"\n", 0, offset) + low + 1


# Bytes str.strip() removes (trimesh strips an OBJ's text before it reads it).
_STRIPPED = np.zeros(256, dtype=bool)
_STRIPPED[list(b" \t\n\r\v\f\x1c\x1d\x1e\x1f")] = True


def _last_other_than_stripped(data: bytes) -> int:
    """The position of the last byte of ``data`` str.strip() keeps, else -1:
    from the end in growing blocks (no copy of the file, whatever its tail)."""
    a = np.frombuffer(data, dtype=np.uint8)
    size = 4096
    while True:
        tail = a[-size:]
        kept = np.flatnonzero(~_STRIPPED[tail])
        if kept.size:
            return a.size - tail.size + int(kept[-1])
        if tail.size == a.size:
            return -1
        size *= 8


def _obj_zero_index_offset(data: bytes) -> int | None:
    """The offset of the first zero index in ``data`` (see
    :func:`_obj_zero_index_line`), else None."""
    a = np.frombuffer(data, dtype=np.uint8)
    n, start = a.size, 0
    last_newline = last_hash = -1  # before the chunk: the line it starts inside of, and any comment on it
    while start < n:
        end = min(start + _ZERO_INDEX_CHUNK, n)
        if end < n and a[end] == ord("0"):  # never split a run of zeros between chunks
            m = _NOT_ZERO.search(data, end)
            end = m.start() if m else n
        chunk = a[start:end]
        newlines = np.concatenate(([last_newline], np.flatnonzero(chunk == ord("\n")) + start))
        hashes = np.concatenate(([last_hash], np.flatnonzero(chunk == ord("#")) + start))
        last_newline, last_hash = int(newlines[-1]), int(hashes[-1])
        zero = np.zeros(chunk.size + 2, dtype=np.int8)
        zero[1:-1] = chunk == ord("0")
        edges = np.diff(zero)
        del zero
        first = np.flatnonzero(edges == 1) + start  # each run of zeros: its first byte
        after = np.flatnonzero(edges == -1) + start  # and the byte after its last
        del edges
        before = a[np.maximum(first - 1, 0)]
        before2 = a[np.maximum(first - 2, 0)]
        token = (first >= 2) & (_BEFORE_INDEX[before] | (_SIGN[before] & _BEFORE_INDEX[before2]))
        token &= (after == n) | _AFTER_INDEX[a[np.minimum(after, n - 1)]]
        first = first[token]
        if first.size:
            line_start = newlines[np.searchsorted(newlines, first) - 1] + 1  # newlines[0] < every token
            face = (a[line_start] == ord("f")) & _BEFORE_INDEX[a[line_start + 1]]
            commented = hashes[np.searchsorted(hashes, first) - 1] >= line_start
            hit = np.flatnonzero(face & ~commented)
            if hit.size:
                return int(first[hit[0]])
        start = end
    return None


def _baked(scene, max_faces: int):
    """``vertices, faces, vertex_normals, uv`` of every mesh instance of a
    trimesh scene, each moved by its node's transform (trimesh's
    ``apply_transform``: normals by the inverse transpose, and faces turned
    over under a mirroring transform, as glTF prescribes); ``uv`` only when
    every instance has one per vertex.  Raises MeshError past ``max_faces``."""
    import trimesh

    nodes = [(node, *scene.graph[node]) for node in scene.graph.nodes_geometry]
    nodes = [(transform, scene.geometry[name]) for _, transform, name in nodes
             if isinstance(scene.geometry.get(name), trimesh.Trimesh)]
    total = sum(len(geometry.faces) for _, geometry in nodes)
    if total > max_faces:
        raise MeshError(f"has {total} triangles; the limit is {max_faces}")
    vertices, faces, normals, uvs, offset = [], [], [], [], 0
    for transform, geometry in nodes:
        # the cache holds the normals the file gave; a plain copy would drop them
        piece = geometry.copy(include_cache=True)
        piece.apply_transform(transform)
        vertices.append(np.asarray(piece.vertices, dtype=np.float64).reshape(-1, 3))
        faces.append(np.asarray(piece.faces, dtype=np.int64).reshape(-1, 3))
        if faces[-1].size and (faces[-1].min() < 0 or faces[-1].max() >= vertices[-1].shape[0]):
            # before trimesh computes normals from them (it logs its own complaints)
            raise MeshError(f"has face indices out of range (it has {vertices[-1].shape[0]} vertices)")
        faces[-1] += offset
        offset += vertices[-1].shape[0]
        if not np.isfinite(vertices[-1]).all():
            raise MeshError("has NaN or infinite vertex coordinates")
        try:  # optional attributes; a mesh without them is still a mesh
            normals.append(np.asarray(piece.vertex_normals, dtype=np.float64).reshape(-1, 3))
        except Exception:
            normals.append(None)
        uv = getattr(piece.visual, "uv", None)
        uvs.append(np.asarray(uv, dtype=np.float64).reshape(-1, 2) if uv is not None and len(uv) == len(vertices[-1])
                   else None)
    if not nodes:
        return np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64), None, None
    join = lambda parts: np.concatenate(parts) if all(p is not None for p in parts) else None  # noqa: E731
    return np.concatenate(vertices), np.concatenate(faces), join(normals), join(uvs)


def declared_triangles(path: str) -> int:
    """The triangles a glTF/GLB file declares (:func:`_gltf_triangles`), read
    from its JSON alone, so that a small file instancing a mesh many times can
    be refused within a memory budget before trimesh builds them; 0 for other
    formats (their size bounds what they hold) and for what cannot be read."""
    return _gltf_triangles(_gltf_json(path))


def referenced_files(path: str) -> dict[str, str]:
    """The files a glTF names by URI (its buffers, and its images, which are
    never read), by where it names them (``images[0]``), so that no output of
    the command replaces one; empty for other formats (read alone) and for
    what cannot be read."""
    from urllib.parse import unquote

    doc, root, files = _gltf_json(path), os.path.dirname(path), {}
    for key in ("buffers", "images"):
        items = doc.get(key) if isinstance(doc, dict) else None
        for i, item in enumerate(items if isinstance(items, list) else []):
            uri = item.get("uri") if isinstance(item, dict) else None
            if isinstance(uri, str) and not uri.startswith("data:"):
                files[f"{key}[{i}]"] = os.path.join(root, unquote(uri))
    return files


def _gltf_json(path: str) -> dict | None:
    """A glTF/GLB file's JSON read from the file, or None (another format, or unreadable)."""
    ext = os.path.splitext(path)[1].lower().lstrip(".")
    if ext not in ("glb", "gltf"):
        return None
    try:
        if not stat.S_ISREG(os.stat(path).st_mode):  # a FIFO would block, /dev/zero stream: read_mesh refuses them
            return None
        with open(path, "rb") as f:
            if ext == "gltf":
                return _gltf_document(f.read(MAX_MESH_BYTES + 1), ext)
            head = f.read(20)
            length = int.from_bytes(head[12:16], "little")
            return _gltf_document(head + f.read(min(length, MAX_MESH_BYTES)), ext)
    except OSError:
        return None


def _without_images(data: bytes, doc: dict | None, ext: str) -> bytes:
    """The glTF/GLB file ``data`` with no images, textures or samplers and
    with materials that refer to none (edits ``doc`` to match).

    wavefront takes a mesh's material from the scene, and trimesh decodes
    every image a glTF holds or names while loading its materials: a 420 KB
    PNG of 12000x12000 pixels took a render under ``--memory 256M`` to 1.2
    GB.  The materials stay (as empty ones, so their indices hold): trimesh
    reads a primitive's UVs only in its material's branch.
    """
    import json

    if doc is None or not any(key in doc for key in ("images", "textures", "samplers", "materials")):
        return data
    materials = doc.get("materials")
    for key in ("images", "textures", "samplers"):
        doc.pop(key, None)
    if isinstance(materials, list):
        doc["materials"] = [{} for _ in materials]
    text = json.dumps(doc, separators=(",", ":"), ensure_ascii=False).encode()  # not inflated by escapes
    if ext == "gltf":
        return text
    text += b" " * (-len(text) % 4)  # GLB chunks are 4-byte aligned, JSON padded with spaces
    rest = data[20 + int.from_bytes(data[12:16], "little"):]
    total = 12 + 8 + len(text) + len(rest)
    return data[:8] + total.to_bytes(4, "little") + len(text).to_bytes(4, "little") + b"JSON" + text + rest


def _gltf_document(data: bytes, ext: str) -> dict | None:
    """A glTF's JSON (a GLB's first chunk), or None if it cannot be read
    (trimesh then reports the file)."""
    import json

    try:
        if ext == "glb":
            length = int.from_bytes(data[12:16], "little")
            if data[16:20] != b"JSON":
                return None
            data = data[20:20 + length]
        doc = json.loads(data)
    except (ValueError, RecursionError):
        return None
    return doc if isinstance(doc, dict) else None


def _gltf_references(doc: dict | None) -> None:
    """Refuse a glTF whose meshes name an accessor it does not have, or whose
    accessors name a buffer view it does not have, naming the JSON path:
    trimesh's own message for ``"POSITION": 5`` of a file without accessors
    was "cannot access local variable 'access' where it is not associated
    with a value"."""
    if not isinstance(doc, dict):
        return

    def items(key):
        value = doc.get(key, [])
        return value if isinstance(value, list) else []

    def check(index, path: str, key: str) -> None:
        if isinstance(index, bool) or not isinstance(index, int) or not 0 <= index < len(items(key)):
            raise MeshError(f"{path} is {json_text(index)}, but the file has {len(items(key))} {key}")

    def json_text(value) -> str:
        import json
        text = json.dumps(value)
        return text if len(text) <= 40 else text[:40] + "..."

    for m, mesh in enumerate(items("meshes")):
        primitives = mesh.get("primitives", []) if isinstance(mesh, dict) else []
        for p, primitive in enumerate(primitives if isinstance(primitives, list) else []):
            if not isinstance(primitive, dict):
                continue
            where = f"meshes[{m}].primitives[{p}]"
            attributes = primitive.get("attributes", {})
            for name, index in (attributes.items() if isinstance(attributes, dict) else ()):
                check(index, f"{where}.attributes.{name}", "accessors")
            if "indices" in primitive:
                check(primitive["indices"], f"{where}.indices", "accessors")
    for a, accessor in enumerate(items("accessors")):
        if isinstance(accessor, dict) and "bufferView" in accessor:
            check(accessor["bufferView"], f"accessors[{a}].bufferView", "bufferViews")
    for v, view in enumerate(items("bufferViews")):
        if isinstance(view, dict) and "buffer" in view:
            check(view["buffer"], f"bufferViews[{v}].buffer", "buffers")


def _gltf_triangles(doc: dict | None) -> int:
    """About the triangles a glTF/GLB file makes trimesh build: each mesh's
    (from its accessors' counts) once per node that instances it, and once if
    none does (a mesh used by many nodes makes a small file declare billions).
    0 when the JSON cannot be read."""
    try:
        accessors = doc.get("accessors", [])

        def triangles(mesh) -> int:
            n = 0
            for primitive in mesh.get("primitives", []):
                index = primitive.get("indices", primitive.get("attributes", {}).get("POSITION"))
                if isinstance(index, int) and 0 <= index < len(accessors):
                    count = accessors[index].get("count", 0)
                    count = count if isinstance(count, int) and count > 0 else 0
                    n += count // 3 if primitive.get("mode", 4) == 4 else count  # strips, fans: one a vertex
            return n

        per_mesh = [triangles(m) for m in doc.get("meshes", [])]
        uses = [0] * len(per_mesh)
        for node in doc.get("nodes", []):
            if isinstance(node.get("mesh"), int) and 0 <= node["mesh"] < len(per_mesh):
                uses[node["mesh"]] += 1
        return sum(n * max(1, k) for n, k in zip(per_mesh, uses))
    except (TypeError, AttributeError, KeyError, IndexError, ValueError):
        return 0


def _gltf_files(doc: dict | None, directory: str, budget: int) -> dict[str, bytes]:
    """The buffers a glTF names by URI (its ``.bin`` files), read for
    trimesh, which is given the file's bytes and so cannot find them itself:
    only regular files inside the glTF's directory (trimesh's own rule), at
    most ``budget`` bytes in all.  (Images are gone: :func:`_without_images`.)"""
    from urllib.parse import unquote

    files, root = {}, os.path.realpath(directory or ".")
    try:
        uris = [item.get("uri") for item in doc.get("buffers", [])]
    except (TypeError, AttributeError):
        return files
    for uri in uris:
        if not isinstance(uri, str) or uri.startswith("data:") or uri in files:
            continue
        try:
            path = os.path.realpath(os.path.join(root, unquote(uri)))
            if os.path.commonpath([root, path]) != root:
                raise MeshError(f"refers to {uri!r}, outside its directory")
            info = os.stat(path)
            if not stat.S_ISREG(info.st_mode):
                raise MeshError(f"refers to {uri!r}, which is not a regular file")
            if info.st_size > budget:
                raise MeshError(f"refers to {uri!r}, which takes it past {MAX_MESH_BYTES} bytes")
            with open(path, "rb") as f:
                files[uri] = f.read(budget + 1)
            budget -= len(files[uri])
            if budget < 0:
                raise MeshError(f"refers to {uri!r}, which takes it past {MAX_MESH_BYTES} bytes")
        except (OSError, ValueError) as e:
            if isinstance(e, MeshError):
                raise
            raise MeshError(f"refers to {uri!r}, which cannot be read: {getattr(e, 'strerror', None) or e}") from None
    return files


def _text_as_utf8(data: bytes, ext: str) -> bytes:
    """A text mesh file's bytes as UTF-8.  trimesh decodes text as UTF-8 and
    otherwise needs charset-normalizer (not installed) to guess, so an OBJ with
    one Latin-1 byte in a comment ("Créé par ...") was refused.  Only comments
    and names can hold such bytes; read as Latin-1 (which maps every byte) the
    numbers are unchanged.  Binary data is left alone: a binary STL (its
    triangle count matches its size), a PLY's body (only its header is text)."""
    def utf8(text: bytes) -> bytes:
        if text.isascii():  # nearly every mesh file: no copy made to find out
            return text
        try:
            text.decode("utf-8")
            return text
        except UnicodeDecodeError:
            return text.decode("latin-1").encode("utf-8")

    if ext in ("obj", "off"):
        return utf8(data)
    if ext == "stl":
        binary = len(data) >= 84 and 84 + 50 * int.from_bytes(data[80:84], "little") == len(data)
        return data if binary else utf8(data)
    if ext == "ply":
        end = _ply_header_end(data)
        if end is not None and not data[:end].isascii():  # no copy of the file for an ASCII header
            return utf8(data[:end]) + data[end:]
    return data


def _ply_header_end(data: bytes) -> int | None:
    """Where a PLY's body starts as trimesh reads the header: after the first
    line from the third holding the word ``end_header`` (:func:`_ply_header`)."""
    second = data.find(b"\n", data.find(b"\n") + 1)
    position = second + 1
    while second >= 0:
        at = data.find(b"end_header", position)
        if at < 0:
            return None
        start = data.rfind(b"\n", 0, at) + 1
        end = data.find(b"\n", at)
        end = len(data) if end < 0 else end
        if "end_header" in _header_text(data[start:end]).split():
            return min(end + 1, len(data))
        position = end + 1
    return None


def mesh_triangles(mesh: Mesh) -> dict:
    """World-space triangle arrays of ``mesh``: ``v0, v1, v2 (3, F)`` and, when
    smooth, ``vertex_normal (3, 3, F)``; ``vertex_uv (3, 2, F)`` if the file has uv."""
    t = mesh.transform
    vertices = mesh.vertices.T
    f = mesh.faces.T
    if t is not None:
        vertices = t.points(vertices)  # once per vertex, at compile time
        if np.linalg.det(t.array[:3, :3]) < 0:
            # a mirror turns every winding over: without turning it back, each face's front
            # (the side it emits from, and the side its file normals are on) would swap sides
            f = f[[0, 2, 1]]
    out = dict(v0=vertices[:, f[0]], v1=vertices[:, f[1]], v2=vertices[:, f[2]], vertex_normal=None, vertex_uv=None)
    if mesh.smooth and mesh.vertex_normals is not None:
        n = mesh.vertex_normals.T
        if t is not None:
            n = t.normals(n)
        n = n / np.maximum(np.linalg.norm(n, axis=0), np.finfo(np.float64).tiny)
        out["vertex_normal"] = np.stack((n[:, f[0]], n[:, f[1]], n[:, f[2]]))
    if mesh.uv is not None:
        uv = mesh.uv.T
        out["vertex_uv"] = np.stack((uv[:, f[0]], uv[:, f[1]], uv[:, f[2]]))
    return out
