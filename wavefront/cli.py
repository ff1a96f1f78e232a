"""Command line: ``wavefront render SCENE -o OUT [options]``.

Bad input (a malformed scene, a bad flag, an unwritable output) is reported
as one line naming the file and what is wrong, with exit status 2, no
traceback, and no output file written or clobbered.  Every file the command
will write (image, frames, checkpoint) is checked before the scene is even
loaded; see :mod:`wavefront.output` for the policy (only regular files are
replaced, symlinks are written through, read-only files are left alone).

Signals: during the render, the first Ctrl-C or SIGTERM stops it and writes
the partial image; at any other moment (loading, planning, writing), or the
second time, the command gives up at once, writes nothing, and exits with
``128 + signal``.
"""

from __future__ import annotations

import argparse
import contextlib
import gc
import os
import re
import signal
import sys
import tempfile
import time
import warnings

EXIT_BAD_INPUT = 2
EXIT_FAILURE = 1  # the render itself failed (its workers kept dying)


class Interrupted(KeyboardInterrupt):
    """A signal asked the command to give up now (not a graceful stop)."""

    def __init__(self, signum: int):
        super().__init__(signum)
        self.signum = signum


def _limits():
    """The scene's limits, which flags share."""
    from . import scene

    return scene


_INTEGER = re.compile(r"^\s*[-+]?[0-9]+\s*$")


def _integer(text: str, low: int, high: int, what: str) -> int:
    if not _INTEGER.match(text):  # int() also takes "1_000" and non-ASCII digits
        raise argparse.ArgumentTypeError(f"expected {what}, got {text!r}")
    value = int(text)
    if not low <= value <= high:
        raise argparse.ArgumentTypeError(f"expected {what} in [{low}, {high:,}], got {text!r}")
    return value


def _side(text: str) -> int:
    return _integer(text, 1, _limits().MAX_PIXELS, "a positive integer")


def _spp(text: str) -> int:
    return _integer(text, 1, _limits().MAX_SAMPLES_PER_PIXEL, "a positive integer")


def _depth(text: str) -> int:
    # 0 is whitted's "no reflections"; the path integrator refuses it with the scene's own message
    return _integer(text, 0, _limits().MAX_DEPTH, "a non-negative integer")


def _positive_int(text: str) -> int:
    return _integer(text, 1, 1 << 31, "a positive integer")


def _workers(text: str) -> int:
    from .render import MAX_WORKERS

    return _integer(text, 1, MAX_WORKERS, "a positive integer")


MAX_FRAMES = 100_000  # a turntable an hour long at 24 frames a second, with room to spare


def _frames(text: str) -> int:
    return _integer(text, 1, MAX_FRAMES, "a positive integer")


def _seed(text: str) -> int:
    return _integer(text, 0, _limits().MAX_SEED, "a non-negative integer")


def _sampler(text: str) -> str:
    choices = _limits().SAMPLERS
    if text not in choices:
        raise argparse.ArgumentTypeError(f"expected {' or '.join(choices)}, got {text!r}")
    return text


def _positive_float(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a positive number, got {text!r}") from None
    if not value > 0 or value == float("inf"):
        raise argparse.ArgumentTypeError(f"expected a positive number, got {text!r}")
    return value


_SIZE = re.compile(r"^\s*([0-9]{1,15}(?:\.[0-9]{1,9})?)\s*(?:([kmgt])(i)?)?(b)?\s*$", re.IGNORECASE)
_SCALE = {None: 1, "k": 1 << 10, "m": 1 << 20, "g": 1 << 30, "t": 1 << 40}


def _memory(text: str) -> int:
    """Sizes like ``512M``, ``2GiB``, ``1.5g``, ``1073741824`` or ``1073741824B``
    (binary units), within the machine's memory."""
    from .memory import MIN_MEMORY, physical_memory

    m = _SIZE.match(text)
    if not m:
        raise argparse.ArgumentTypeError(f"expected a size such as 512M or 2G, got {text!r}")
    value = int(float(m.group(1)) * _SCALE[m.group(2) and m.group(2).lower()])
    if value < MIN_MEMORY:
        raise argparse.ArgumentTypeError(f"at least {MIN_MEMORY >> 20}M is needed, got {text!r}")
    physical = physical_memory()
    if value > physical:
        raise argparse.ArgumentTypeError(f"{text!r} is more than this machine's memory "
                                         f"({physical / 2**30:,.1f} GiB)")
    return value


def _version() -> str:
    # the package's own attribute (pyproject.toml's version is read from it):
    # importlib.metadata would cost ~15 ms of every command (email, csv, zipfile, a scan of sys.path)
    from wavefront import __version__

    return __version__


class _Parser(argparse.ArgumentParser):
    """argparse, but a bad argument is one line (the usage block is in --help)."""

    def error(self, message):
        _say(f"{self.prog}: error: {message} (see {self.prog} --help)")  # an argument may hold control characters
        self.exit(EXIT_BAD_INPUT)


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="wavefront", description="A NumPy wavefront path tracer.")
    parser.add_argument("--version", action="version", version=f"wavefront {_version()}")
    sub = parser.add_subparsers(dest="command", required=True)
    r = sub.add_parser("render", help="render a YAML scene to PNG, EXR or NPY")
    r.add_argument("scene", help="YAML scene file")
    r.add_argument("-o", "--output", required=True, help="output image: .png (sRGB), .exr or .npy (linear)")
    r.add_argument("--width", type=_side, help="image width (alone: keeps the aspect ratio)")
    r.add_argument("--height", type=_side, help="image height (alone: keeps the aspect ratio)")
    r.add_argument("--spp", type=_spp, help="samples per pixel")
    r.add_argument("--max-depth", type=_depth, help="path segments (path) or recursion depth (whitted)")
    r.add_argument("--seed", type=_seed, help="random seed; the same seed gives the same image")
    r.add_argument("--sampler", type=_sampler, metavar="{sobol,independent}",
                   help="where the random numbers come from (default: the scene's render.sampler, else sobol)")
    r.add_argument("--workers", type=_workers,
                   help="processes (default: all cores, fewer if --memory needs it); the image does not change")
    r.add_argument("--memory", type=_memory,
                   help="memory budget for the whole process tree, e.g. 512M (default 1G)")
    r.add_argument("--chunk-size", type=_positive_int, help="paths in flight per worker (default: from --memory)")
    r.add_argument("--checkpoint", metavar="FILE.npz", help="save progress to FILE.npz periodically and on exit")
    r.add_argument("--checkpoint-interval", type=_positive_float, default=30.0, metavar="SECONDS",
                   help="seconds between checkpoints (default 30)")
    r.add_argument("--resume", metavar="FILE.npz", help="continue the render saved in checkpoint FILE.npz")
    r.add_argument("--scheduler", metavar="ADDRESS",
                   help="render on a Dask cluster: tcp://HOST:8786, or local:N to start N local workers")
    r.add_argument("--frames", type=_frames, metavar="N",
                   help="render a turntable of N frames around look_at; OUT names them with {frame}, "
                        "e.g. spin_{frame:03d}.png")
    r.add_argument("-q", "--quiet", action="store_true", help="no progress bar or summary")
    return parser


# C0 and C1 control characters and DEL: a newline in a file name or YAML key
# split a message into two lines (the second could pose as another error),
# and ESC sequences in one drove the terminal
_CONTROL = re.compile("[\x00-\x1f\x7f-\x9f]")


def _say(text: str) -> None:
    """One line on standard error, control characters shown as escapes (``\\n``, ``\\x1b``)."""
    print(_CONTROL.sub(lambda m: repr(m.group())[1:-1], text), file=sys.stderr)


def _warn_line(message, category, filename, lineno, file=None, line=None):
    _say(f"wavefront: warning: {message}")


class _Signals:
    """Where the command is decides what a signal means (see the module doc)."""

    def __init__(self):
        self.rendering = False
        self.stop = None  # the signal that asked the render to stop
        self.pid = os.getpid()

    def __call__(self, signum, frame):
        if os.getpid() != self.pid:
            # A worker forked before its initializer reset the handlers: a
            # SIGTERM (say, to the whole process group) must end it; an
            # interrupt is the parent's to handle.
            if signum == signal.SIGTERM:
                signal.signal(signum, signal.SIG_DFL)
                os.kill(os.getpid(), signum)
            return
        if self.rendering and self.stop is None:
            self.stop = signum
            return
        raise Interrupted(signum)


def main(argv: list[str] | None = None) -> int:
    started = time.perf_counter()
    signals = _Signals()
    # a signal ignored when the command started (SIGINT for a shell's
    # background job) stays ignored, as POSIX tools do
    previous = {sig: signal.signal(sig, signals) for sig in (signal.SIGINT, signal.SIGTERM)
                if signal.getsignal(sig) is not signal.SIG_IGN}
    try:
        args = build_parser().parse_args(argv)
        warnings.showwarning = _warn_line
        return _render(args, signals, started)
    except Interrupted as e:
        name = signal.Signals(e.signum).name
        _say(f"wavefront: interrupted ({name}); nothing was written")
        return 128 + e.signum
    except KeyboardInterrupt:
        _say("wavefront: interrupted; nothing was written")
        return 128 + signal.SIGINT
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)


def command() -> int:
    """The ``wavefront`` console script (and ``python -m wavefront``): :func:`main`,
    then a quick exit.

    The interpreter's last garbage collection at exit walks every object the
    process holds, NumPy's and every module's: ~25 ms of a 0.3 s command.
    Frozen, they are left to the operating system.  Nothing is lost: files
    are written and closed before :func:`main` returns, atexit handlers and
    the flushing of stdout and stderr still run, and Python never promised to
    finalize objects still alive at exit.  Not done in :func:`main`, which
    the tests and the Python API may call in a process that goes on.
    """
    status = main()
    gc.freeze()
    return status


MAX_NAME_BYTES = 255  # a file name (Linux's NAME_MAX, and most file systems')
MAX_PATH_BYTES = 4096  # a whole path (Linux's PATH_MAX)
MAX_FRAME_NAME_BYTES = 64 << 20  # all of --frames' names together


def frame_paths(output: str, frames: int | None) -> list[str]:
    """Output path of each frame: ``{frame}`` formatted, or ``_0000`` before the extension."""
    if "\0" in output:
        raise ValueError(f"{output!r}: a file name cannot contain a NUL byte")
    if frames is None:
        if "{frame" in output:
            raise ValueError(f"{output}: names {{frame}} but --frames was not given")
        return [output]
    if "{frame" in output:
        paths, total = [], 0
        for k in range(frames):
            try:
                path = output.format(frame=k)
            except (ValueError, KeyError, IndexError, AttributeError, TypeError) as e:
                raise ValueError(f"{output}: bad {{frame}} pattern ({e})") from None
            # checked as made: a pattern like {frame:>5000} built 100,000 names (500 MB) before
            # the first write refused them, in a message of 5,000 characters
            try:
                encoded = os.fsencode(path)
            except UnicodeEncodeError:  # {frame:c} of 55296 is a lone surrogate: no file name holds it
                raise ValueError(f"{output[:200]}: the {{frame}} pattern makes frame {k}'s file name "
                                 f"{path[:200]!r}, which cannot be a file name (--frames)") from None
            size = len(encoded)
            if size > MAX_PATH_BYTES or max(map(len, encoded.split(b"/"))) > MAX_NAME_BYTES:
                raise ValueError(f"{output[:200]}: the {{frame}} pattern makes a file name longer than the "
                                 f"system allows ({MAX_NAME_BYTES} bytes a name, {MAX_PATH_BYTES} a path)")
            total += size
            if total > MAX_FRAME_NAME_BYTES:
                raise ValueError(f"{output[:200]}: the frames' file names take more than "
                                 f"{MAX_FRAME_NAME_BYTES >> 20} MiB")
            paths.append(path)
    else:
        stem, ext = os.path.splitext(output)
        paths = [f"{stem}_{k:04d}{ext}" for k in range(frames)]
    if len(set(paths)) != len(paths):
        raise ValueError(f"{output}: the {{frame}} pattern gives two frames the same file name")
    if any("\0" in path for path in paths):
        raise ValueError(f"{output!r}: the {{frame}} pattern makes a file name with a NUL byte")
    return paths


def check_paths(args) -> list[str]:
    """Check every file the command reads or writes, before anything else.

    Returns the output path of each frame.  Raises ``OutputError``.  Linear
    in the number of frames: files are compared by identity keys, and each
    directory is probed once.
    """
    from .output import OutputError, check_output_path, file_key

    if args.frames is not None and (args.checkpoint or args.resume):
        raise OutputError("--checkpoint and --resume work on single images, not --frames")
    try:
        outputs = frame_paths(args.output, args.frames)
    except ValueError as e:
        raise OutputError(str(e)) from None
    probed = set()
    for out in outputs:
        target = check_output_path(out, probe=os.path.dirname(os.path.realpath(out)) not in probed)
        probed.add(os.path.dirname(target))
    writes = [(f"frame {k}" if args.frames is not None else "-o", out) for k, out in enumerate(outputs)]
    if args.checkpoint is not None:
        if not args.checkpoint.endswith(".npz"):
            raise OutputError(f"{args.checkpoint}: a checkpoint file name must end in .npz (--checkpoint)")
        check_output_path(args.checkpoint, image=False)
        same_as_resume = args.resume is not None and file_key(args.resume) == file_key(args.checkpoint)
        if os.path.exists(args.checkpoint) and not same_as_resume:
            raise OutputError(f"{args.checkpoint}: already exists (an earlier render's progress?); continue it "
                              "with --resume and the same file, or remove it first (--checkpoint)")
        writes.append(("--checkpoint", args.checkpoint))
    reads = {file_key(args.scene): "the scene"}
    if args.resume is not None:
        reads[file_key(args.resume)] = "--resume"
    seen = {}
    for flag, path in writes:
        key = file_key(path)
        if key in seen:
            raise OutputError(f"{path}: {seen[key]} and {flag} name the same file")
        seen[key] = flag
        what = reads.get(key)
        # resuming and saving to the same checkpoint is how a render is continued
        if what is not None and not (what == "--resume" and flag == "--checkpoint"):
            raise OutputError(f"{path}: {flag} would overwrite {what}")
    if args.resume is not None:
        if not os.path.exists(args.resume):
            raise OutputError(f"{args.resume}: no such checkpoint file")
        if not os.path.isfile(args.resume):
            raise OutputError(f"{args.resume}: not a regular file (--resume)")
    return outputs


def scene_inputs(scene) -> dict[str, str]:
    """Every file the scene reads besides itself, by YAML path: image
    textures (nested in checkers too) and mesh files, media boundaries' included."""
    import dataclasses

    from .shapes.mesh import referenced_files
    from .textures import Checker, ImageTexture

    files = {}

    def texture(value, path):
        if isinstance(value, ImageTexture) and value.file is not None:
            files[f"{path}.file"] = value.file
        elif isinstance(value, Checker):
            texture(value.even, f"{path}.even")
            texture(value.odd, f"{path}.odd")

    for name, material in scene.materials.items():
        for f in dataclasses.fields(material):
            texture(getattr(material, f.name), f"materials.{name}.{f.name}")
    meshes = [(f"meshes[{i}].file", m.file) for i, m in enumerate(scene.meshes) if m.file]
    meshes += [(f"media[{i}].boundary.mesh.file", m.boundary.file) for i, m in enumerate(scene.media)
               if getattr(m.boundary, "file", "")]
    for path, file in meshes:
        files[path] = file
        for where, other in referenced_files(file).items():  # a glTF's .bin buffers and images
            files[f"{path}, whose {os.path.basename(file)} names it in {where}"] = other
    return files


def check_not_reading(scene, writes: list[str]) -> None:
    """Refuse an output that names a file the scene reads (``-o earthmap.png``
    beside a scene textured with it would replace the texture).  Raises
    ``OutputError``; checked once the scene is loaded, before rendering."""
    from .output import OutputError, file_key

    reads = {file_key(file): (path, file) for path, file in scene_inputs(scene).items()}
    for out in writes:
        if file_key(out) in reads:
            path, file = reads[file_key(out)]
            raise OutputError(f"{out}: would overwrite {file}, which the scene reads ({path})")


def _render(args, signals: _Signals, started: float) -> int:
    from .film import CheckpointError
    from .output import OutputError, encode_bytes
    from .render import DEFAULT_MEMORY, MemoryBudgetError, RenderError, compile_within, phase_peak, render_scene
    from .scene import turntable
    from .scenefile import SceneError, load_scene

    memory = args.memory or DEFAULT_MEMORY
    try:
        outputs = check_paths(args)
        _refuse_unless_loading_fits(args.scene, memory)
        scene = load_scene(args.scene, memory=memory)
        scene = _with_flags(scene, args)
        check_not_reading(scene, outputs + ([args.checkpoint] if args.checkpoint is not None else []))
        _check_frames(scene, args)  # every frame checked before the first is rendered
    except (SceneError, OutputError) as e:
        _say(f"wavefront: error: {e}")
        return EXIT_BAD_INPUT
    except MemoryBudgetError as e:
        _say(f"wavefront: error: {_naming(args.scene, e)} (--memory)")
        return EXIT_BAD_INPUT
    _remove_stale_temporaries(outputs + ([args.checkpoint] if args.checkpoint is not None else []))
    loaded = time.perf_counter()

    executor, client, workers = None, None, args.workers
    if args.scheduler is not None:
        from .distributed import (SchedulerError, connect, dask_executor, local_worker_count,
                                  refuse_unless_local_render_fits)

        try:
            local_worker_count(args.scheduler, memory)  # the workers fit at all, before planning for them
            refuse_unless_local_render_fits(args.scheduler, scene, memory, chunk_size=args.chunk_size,
                                            output_bytes=max(encode_bytes(scene.width, scene.height, out)
                                                             for out in outputs))
            client = connect(args.scheduler, memory)
        except SchedulerError as e:
            _say(f"wavefront: error: {e}")
            return EXIT_BAD_INPUT
        except MemoryBudgetError as e:
            _say(f"wavefront: error: {_naming(args.scene, e)} (--memory)")
            return EXIT_BAD_INPUT
        executor = dask_executor(client, local_workers=local_worker_count(args.scheduler))
        workers = max(1, len(client.scheduler_info().get("workers", {})))

    samples_per_frame = scene.width * scene.height * scene.render.samples_per_pixel
    bar = None
    if not args.quiet and sys.stderr.isatty():
        from tqdm import tqdm

        bar = tqdm(total=len(outputs) * samples_per_frame, unit="samples", unit_scale=True, file=sys.stderr,
                   leave=False)
    try:
        for k, out in enumerate(outputs):
            frame_scene = scene if args.frames is None else turntable(scene, k, args.frames)

            def progress(done: int, total: int, offset=k * samples_per_frame) -> None:
                if bar is not None:
                    bar.update(offset + done - bar.n)

            try:
                # compiled before the render starts, so a signal meanwhile gives up
                # at once instead of stopping a render that never began
                compiled = None if executor is not None else compile_within(frame_scene, memory)
                signals.rendering = True
                result = render_scene(frame_scene, workers=workers, memory=memory, chunk_size=args.chunk_size,
                                      progress=progress, should_stop=lambda: signals.stop is not None,
                                      checkpoint=args.checkpoint, checkpoint_interval=args.checkpoint_interval,
                                      resume=args.resume, executor=executor, compiled=compiled,
                                      output_bytes=encode_bytes(scene.width, scene.height, out))
            except (CheckpointError, OutputError) as e:
                _say(f"wavefront: error: {e}")
                return EXIT_BAD_INPUT
            except MemoryBudgetError as e:
                _say(f"wavefront: error: {_naming(args.scene, e)} (--memory)")
                return EXIT_BAD_INPUT
            except RenderError as e:
                _say(f"wavefront: error: {e}; nothing was written")
                return EXIT_FAILURE
            finally:
                signals.rendering = False
            s = result.stats
            if s.units_done == 0 and signals.stop is not None:  # stopped before any unit finished: no image
                _say(f"wavefront: interrupted ({signal.Signals(signals.stop).name}) before any sample was "
                     f"finished; nothing was written")
                return 128 + signals.stop
            metadata = {"Software": f"wavefront {_version()}", "wavefront.scene": scene.name,
                        "wavefront.seed": s.seed, "wavefront.samples_per_pixel": scene.render.samples_per_pixel,
                        "wavefront.sampler": scene.render.sampler,
                        "wavefront.partial": "yes" if s.partial else "no",
                        "wavefront.units": f"{s.units_done}/{s.units_total}"}
            if args.frames is not None:
                metadata["wavefront.frame"] = f"{k}/{args.frames}"
            write_start = time.perf_counter()
            written, failure = _write_or_rescue(out, result.film, metadata)
            s.peak_memory = max(s.peak_memory, phase_peak(reset=False))
            if not args.quiet and written is not None:
                if bar is not None:
                    bar.clear()
                timing = Timing(load=loaded - started if k == 0 else 0.0, render=s.elapsed,
                                write=time.perf_counter() - write_start,
                                total=process_age(time.perf_counter() - started))
                _say(summary_line(frame_scene, s, written, timing))
            if failure is not None or s.checkpoint_error is not None:
                for message in (failure, s.checkpoint_error):
                    if message is not None:
                        _say(f"wavefront: error: {message}")
                return EXIT_BAD_INPUT
            if signals.stop is not None:
                return 128 + signals.stop  # the shell's convention for "ended by this signal"
        return 0
    finally:
        if bar is not None:
            bar.close()
        if client is not None:
            client.close()
            if client.cluster is not None:
                client.cluster.close()


def _naming(scene: str, e: Exception) -> str:
    """A budget's message, led by the scene file when it does not name it
    already ("compiling 405,000 primitives needs ..." names no file)."""
    text = str(e)
    return text if text.startswith(("loading ", scene)) else f"{scene}: {text}"


def _remove_stale_temporaries(writes: list[str]) -> None:
    """Clear what killed renders left in the directories this one writes to
    (see :func:`wavefront.output.remove_stale_temporaries`): only once the
    scene and the arguments are accepted, so a refused command changes nothing."""
    from .output import remove_stale_temporaries, resolve_target

    for directory in dict.fromkeys(os.path.dirname(resolve_target(path)) for path in writes):
        remove_stale_temporaries(directory)


def _check_frames(scene, args) -> None:
    """Build the scene of each frame (``--frames``' turntable), validated as
    a scene is, and let it go (each is ~1 KB: 100,000 frames kept would be
    100 MB; the render loop builds each again): a frame whose camera leaves
    the coordinates' range (or cannot be resolved) is refused before any
    frame is rendered, naming the scene file, the YAML path and the frame."""
    from .scene import turntable
    from .scenefile import SceneError
    from .validation import join, source_of

    for k in range(args.frames or 0):
        try:
            turntable(scene, k, args.frames)
        except SceneError as e:
            # the turned camera's own checks name its fields (look_from[0]); the
            # scene's (render.precision, camera.look_from) name their whole path
            path = join("camera", e.path) if e.source == source_of(scene.camera) else e.path
            raise SceneError(args.scene, path, f"in frame {k} of --frames {args.frames} (look_from turned about "
                                               f"look_at): {e.problem}") from None


def _refuse_unless_loading_fits(path: str, memory: int) -> None:
    """Refuse a scene file too big to load within the budget, before reading it."""
    from .memory import refuse_unless_fits
    from .memory import LOAD_BYTES_PER_FILE_BYTE

    try:
        size = os.stat(path).st_size
    except OSError:
        return  # the loader reports it
    refuse_unless_fits(memory, LOAD_BYTES_PER_FILE_BYTE * size, f"loading {path} ({size / 2**20:,.0f} MiB)")


_FLAG_OF = {"width": "--width", "height": "--height", "render.samples_per_pixel": "--spp",
            "render.max_depth": "--max-depth", "render.seed": "--seed", "render.sampler": "--sampler"}


def _with_flags(scene, args):
    """The scene with the command line's overrides, under the scene file's
    own limits; a violation names the flag, not a YAML path."""
    from .scenefile import SceneError

    try:
        return scene.with_overrides(width=args.width, height=args.height, samples_per_pixel=args.spp,
                                    max_depth=args.max_depth, seed=args.seed, sampler=args.sampler)
    except SceneError as e:
        given = {"--width": args.width, "--height": args.height, "--spp": args.spp, "--max-depth": args.max_depth,
                 "--seed": args.seed, "--sampler": args.sampler}
        flags = [_FLAG_OF[e.path]] if e.path in _FLAG_OF else ["--width", "--height"]  # else: the pixel count
        named = " ".join(f"{f} {given[f]}" for f in flags if given[f] is not None)
        raise SceneError(args.scene, named or "image", e.problem) from None


def _write_or_rescue(out: str, film, metadata) -> tuple[str | None, str | None]:
    """Write the image; if that fails after all the checks, save it elsewhere.

    Returns ``(path written, None)`` on success, else ``(where it went or
    None, the message to print)``.  A finished render is never lost to a
    full disk or a directory removed while it ran.
    """
    from .output import OutputError, write_image
    from .validation import first_line

    try:
        write_image(out, film, metadata)
        return out, None
    except OutputError as e:
        problem = f"cannot write the image: {e}"
    except OSError as e:
        problem = f"{out}: cannot write the image: {e.strerror or e}"
    except Exception as e:  # an encoder's own failure (Pillow, OpenEXR): the render is still not lost
        problem = f"{out}: cannot write the image: {first_line(e)}"
    ext = os.path.splitext(out)[1].lower()
    for directory in dict.fromkeys((tempfile.gettempdir(), os.getcwd(), os.path.expanduser("~"))):
        for suffix in dict.fromkeys((ext, ".npy")):
            try:  # a fresh name; the file itself is written anew, with the usual permissions
                fd, rescue = tempfile.mkstemp(prefix="wavefront-rescued-", suffix=suffix, dir=directory)
                os.close(fd)
                os.unlink(rescue)
            except OSError:
                continue
            try:
                write_image(rescue, film, metadata)
                return rescue, f"{problem}; the image was saved to {rescue} instead"
            except Exception:  # noqa: BLE001 - the next place, and at last .npy, which needs no encoder
                with contextlib.suppress(OSError):
                    os.unlink(rescue)
    return None, f"{problem}; no other place to save the image was writable either"


class Timing:
    """Seconds spent in each part of the command, for the summary."""

    def __init__(self, load: float, render: float, write: float, total: float):
        self.load, self.render, self.write, self.total = load, render, write, total


def process_age(fallback: float) -> float:
    """Seconds since this process started (interpreter start-up included),
    from ``/proc``; ``fallback`` where that is not available."""
    try:
        with open("/proc/self/stat") as f:
            start_ticks = int(f.read().rsplit(")", 1)[1].split()[19])
        with open("/proc/uptime") as f:
            uptime = float(f.read().split()[0])
        age = uptime - start_ticks / os.sysconf("SC_CLK_TCK")
        return age if age >= fallback else fallback
    except (OSError, ValueError, IndexError):
        return fallback


def summary_line(scene, s, output: str, timing: Timing | None = None) -> str:
    rate = lambda n: n / s.elapsed if s.elapsed > 0 else float("inf")  # noqa: E731
    parts = [f"{output}: {scene.width}x{scene.height}, {scene.render.samples_per_pixel} spp"]
    if timing is None:
        parts.append(f"render {s.elapsed:.2f} s")
    else:
        parts.append(f"render {timing.render:.2f} s, total {timing.total:.2f} s "
                     f"(load {timing.load:.2f} s, write {timing.write:.2f} s)")
    parts += [
        f"{rate(s.samples) / 1e6:.2f} M samples/s",
        f"{rate(s.segments) / 1e6:.2f} M path segments/s"
        + (f" (+ {rate(s.shadow_rays) / 1e6:.2f} M shadow rays/s)" if s.shadow_rays else ""),
        f"peak memory {s.peak_memory / 2**20:.0f} MiB",
        f"seed {s.seed}" + ("" if scene.render.sampler == "sobol" else f" ({scene.render.sampler} sampler)"),
        f"{s.workers} worker{'s' if s.workers != 1 else ''}",
    ]
    if s.dropped:
        parts.append(f"{s.dropped} non-finite samples dropped")
    if s.partial:
        parts.append(f"PARTIAL ({s.units_done}/{s.units_total} units"
                     + (f", {s.pixels_without_samples} pixels without samples" if s.pixels_without_samples else "")
                     + ")")
    elif s.pixels_without_samples:  # every sample of a pixel dropped (or a checkpoint's, resumed)
        parts.append(f"{s.pixels_without_samples} pixels without samples")
    return ", ".join(parts)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(command())
