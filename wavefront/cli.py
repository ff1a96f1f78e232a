"""Command line: ``wavefront render SCENE -o OUT [options]``.

Bad input (a malformed scene, a bad flag, an unwritable output) is reported
as one line naming the file and what is wrong, with exit status 2, no
traceback, and no output file written or clobbered.
"""

from __future__ import annotations

import argparse
import os
import re
import signal
import sys
import warnings

EXIT_BAD_INPUT = 2


def _positive_int(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {text!r}") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {text!r}")
    return value


def _seed(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a non-negative integer, got {text!r}") from None
    if not 0 <= value < 2**63:
        raise argparse.ArgumentTypeError(f"expected an integer in [0, 2^63), got {text!r}")
    return value


def _positive_float(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a positive number, got {text!r}") from None
    if not value > 0 or value == float("inf"):
        raise argparse.ArgumentTypeError(f"expected a positive number, got {text!r}")
    return value


_SIZE = re.compile(r"^\s*(\d+(?:\.\d+)?)\s*([kmgt]?i?b?)?\s*$", re.IGNORECASE)


def _memory(text: str) -> int:
    """Sizes like ``512M``, ``2GiB``, ``1.5g`` or plain bytes."""
    m = _SIZE.match(text)
    if not m:
        raise argparse.ArgumentTypeError(f"expected a size such as 512M or 2G, got {text!r}")
    scale = {"": 1, "k": 1 << 10, "m": 1 << 20, "g": 1 << 30, "t": 1 << 40}[(m.group(2) or "")[:1].lower()]
    value = int(float(m.group(1)) * scale)
    if value < 64 << 20:
        raise argparse.ArgumentTypeError(f"at least 64M is needed, got {text!r}")
    return value


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="wavefront", description="A NumPy wavefront path tracer.")
    sub = parser.add_subparsers(dest="command", required=True)
    r = sub.add_parser("render", help="render a YAML scene to PNG, EXR or NPY")
    r.add_argument("scene", help="YAML scene file")
    r.add_argument("-o", "--output", required=True, help="output image: .png (sRGB), .exr or .npy (linear)")
    r.add_argument("--width", type=_positive_int, help="image width (alone: keeps the aspect ratio)")
    r.add_argument("--height", type=_positive_int, help="image height (alone: keeps the aspect ratio)")
    r.add_argument("--spp", type=_positive_int, help="samples per pixel")
    r.add_argument("--max-depth", type=_positive_int, help="path segments (path) or recursion depth (whitted)")
    r.add_argument("--seed", type=_seed, help="random seed; the same seed gives the same image")
    r.add_argument("--workers", type=_positive_int, help="processes (default: all cores); the image does not change")
    r.add_argument("--memory", type=_memory, help="memory budget for the render, e.g. 512M (default 1G)")
    r.add_argument("--chunk-size", type=_positive_int, help="paths in flight per worker (default: from --memory)")
    r.add_argument("--checkpoint", metavar="FILE", help="save progress to FILE (.npz) periodically and on exit")
    r.add_argument("--checkpoint-interval", type=_positive_float, default=30.0, metavar="SECONDS",
                   help="seconds between checkpoints (default 30)")
    r.add_argument("--resume", metavar="FILE", help="continue the render saved in checkpoint FILE")
    r.add_argument("--scheduler", metavar="ADDRESS",
                   help="render on a Dask cluster: tcp://HOST:8786, or local:N to start N local workers")
    r.add_argument("--frames", type=_positive_int, metavar="N",
                   help="render a turntable of N frames around look_at; OUT names them with {frame}, "
                        "e.g. spin_{frame:03d}.png")
    r.add_argument("-q", "--quiet", action="store_true", help="no progress bar or summary")
    return parser


def _warn_line(message, category, filename, lineno, file=None, line=None):
    print(f"wavefront: warning: {message}", file=sys.stderr)


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    warnings.showwarning = _warn_line
    try:
        return _render(args)
    except KeyboardInterrupt:
        print("wavefront: interrupted", file=sys.stderr)
        return 130


def frame_paths(output: str, frames: int | None) -> list[str]:
    """Output path of each frame: ``{frame}`` formatted, or ``_0000`` before the extension."""
    if frames is None:
        return [output]
    if "{frame" in output:
        try:
            return [output.format(frame=k) for k in range(frames)]
        except (ValueError, KeyError, IndexError) as e:
            raise ValueError(f"{output}: bad {{frame}} pattern ({e})") from None
    stem, ext = os.path.splitext(output)
    return [f"{stem}_{k:04d}{ext}" for k in range(frames)]


def _render(args) -> int:
    from .output import OutputError, check_output_path, write_image
    from .render import DEFAULT_MEMORY, CheckpointError, image_bytes, render_scene
    from .scene import turntable
    from .scenefile import SceneError, load_scene

    memory = args.memory or DEFAULT_MEMORY
    try:
        if args.frames is not None and (args.checkpoint or args.resume):
            raise OutputError("--checkpoint and --resume work on single images, not --frames")
        try:
            outputs = frame_paths(args.output, args.frames)
        except ValueError as e:
            raise OutputError(str(e)) from None
        for out in outputs:
            check_output_path(out)
        for path in (args.checkpoint, args.resume):
            if path is not None and not os.path.isdir(os.path.dirname(os.path.abspath(path))):
                raise OutputError(f"{path}: directory does not exist")
        if args.resume is not None and not os.path.isfile(args.resume):
            raise OutputError(f"{args.resume}: no such checkpoint file")
        scene = load_scene(args.scene)
        scene = scene.with_overrides(width=args.width, height=args.height, samples_per_pixel=args.spp,
                                     max_depth=args.max_depth, seed=args.seed)
        needed = image_bytes(scene.width, scene.height)
        if needed > memory:
            raise OutputError(f"{scene.width}x{scene.height}: the image alone needs about "
                              f"{needed / 2**20:,.0f} MiB, more than the memory budget of "
                              f"{memory / 2**20:,.0f} MiB (--memory)")
    except (SceneError, OutputError) as e:
        print(f"wavefront: error: {e}", file=sys.stderr)
        return EXIT_BAD_INPUT

    executor, client, workers = None, None, args.workers
    if args.scheduler is not None:
        from .distributed import SchedulerError, connect, dask_executor

        try:
            client = connect(args.scheduler)
        except SchedulerError as e:
            print(f"wavefront: error: {e}", file=sys.stderr)
            return EXIT_BAD_INPUT
        executor = dask_executor(client)
        workers = max(1, len(client.scheduler_info().get("workers", {})))

    scenes = [scene] if args.frames is None else [turntable(scene, k, args.frames) for k in range(args.frames)]
    bar = None
    if not args.quiet and sys.stderr.isatty():
        from tqdm import tqdm

        bar = tqdm(total=len(scenes) * scene.width * scene.height * scene.render.samples_per_pixel,
                   unit="samples", unit_scale=True, file=sys.stderr, leave=False)

    # Ctrl-C or SIGTERM asks the render to stop and keep what it has; a
    # second Ctrl-C gives up at once.
    stop = {"signal": None}

    def request_stop(signum, frame):
        if stop["signal"] is not None and signum == signal.SIGINT:
            raise KeyboardInterrupt
        stop["signal"] = signum

    previous = {sig: signal.signal(sig, request_stop) for sig in (signal.SIGINT, signal.SIGTERM)}
    try:
        for k, (frame_scene, out) in enumerate(zip(scenes, outputs)):
            offset = k * scene.width * scene.height * scene.render.samples_per_pixel

            def progress(done: int, total: int, offset=offset) -> None:
                if bar is not None:
                    bar.update(offset + done - bar.n)

            try:
                result = render_scene(frame_scene, workers=workers, memory=memory, chunk_size=args.chunk_size,
                                      progress=progress, should_stop=lambda: stop["signal"] is not None,
                                      checkpoint=args.checkpoint, checkpoint_interval=args.checkpoint_interval,
                                      resume=args.resume, executor=executor)
            except CheckpointError as e:
                print(f"wavefront: error: {e}", file=sys.stderr)
                return EXIT_BAD_INPUT
            s = result.stats
            metadata = {"Software": "wavefront", "wavefront.scene": scene.name, "wavefront.seed": s.seed,
                        "wavefront.samples_per_pixel": scene.render.samples_per_pixel,
                        "wavefront.partial": "yes" if s.partial else "no",
                        "wavefront.units": f"{s.units_done}/{s.units_total}"}
            if args.frames is not None:
                metadata["wavefront.frame"] = f"{k}/{args.frames}"
            try:
                write_image(out, result.image, metadata)
            except OSError as e:
                print(f"wavefront: error: {out}: cannot write: {e.strerror or e}", file=sys.stderr)
                return EXIT_BAD_INPUT
            if not args.quiet:
                if bar is not None:
                    bar.clear()
                print(summary_line(frame_scene, s, out), file=sys.stderr)
            if stop["signal"] is not None:
                return 128 + stop["signal"]  # the shell's convention for "ended by this signal"
        return 0
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)
        if bar is not None:
            bar.close()
        if client is not None:
            client.close()
            if client.cluster is not None:
                client.cluster.close()


def summary_line(scene, s, output: str) -> str:
    rate = lambda n: n / s.elapsed if s.elapsed > 0 else float("inf")  # noqa: E731
    parts = [
        f"{output}: {scene.width}x{scene.height}, {scene.render.samples_per_pixel} spp",
        f"{s.elapsed:.2f} s",
        f"{rate(s.samples) / 1e6:.2f} M samples/s",
        f"{rate(s.segments) / 1e6:.2f} M path segments/s",
        f"peak memory {s.peak_memory / 2**20:.0f} MiB",
        f"seed {s.seed}",
        f"{s.workers} worker{'s' if s.workers != 1 else ''}",
    ]
    if s.dropped:
        parts.append(f"{s.dropped} non-finite samples dropped")
    if s.partial:
        parts.append(f"PARTIAL ({s.units_done}/{s.units_total} units)")
    return ", ".join(parts)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
