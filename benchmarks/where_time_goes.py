"""Where a render's time goes: one core, cProfile, grouped by stage.

    .venv/bin/python benchmarks/where_time_goes.py scenes/final_scene.yaml
    .venv/bin/python benchmarks/where_time_goes.py scenes/three_spheres.yaml --top 25

Renders the scene once unprofiled (warm-up, and the wall time quoted), then
once under cProfile, and prints the share of the profiled time spent in each
stage of the wavefront (intersection and its parts, scattering, camera rays,
random numbers) followed by the functions with the most time of their own.
Profiling slows NumPy-heavy code less than pure Python, but it still adds
per-call overhead: read the shares, not the absolute times.
"""

from __future__ import annotations

import argparse
import cProfile
import pstats
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

import wavefront  # noqa: E402

# (label, file suffix, function name): cumulative time of each, as a share of the render
STAGES = (
    ("  brute force (the whole scene, or a BVH's outsized primitives)", "primitives.py", "intersect"),
    ("  BVH tree walk", "bvh.py", "_traverse"),
    ("    BVH leaf tests", "bvh.py", "test_leaves"),
    ("brute force's float32 slab filter (in the nearest-hit and the shadow-ray queries)", "primitives.py", "pairs"),
    ("hit points and normals (SurfaceHits)", "primitives.py", "surface"),
    ("camera rays (refill)", "path.py", "camera_paths"),
    ("lambertian kernel", "materials.py", "scatter_lambertian"),
    ("metal kernel", "materials.py", "scatter_metal"),
    ("dielectric kernel", "materials.py", "scatter_dielectric"),
    ("light sampling: choosing points on emitters", "path.py", "sample_lights"),
    ("  emitter samplers", "lights.py", "sample"),
    ("light sampling: shadow rays (any-hit)", "path.py", "trace_shadow_rays"),
    ("MIS weights of emission hits", "path.py", "emission_weight"),
    ("media: the first boundary query (before the hit query)", "path.py", "first_boundaries"),
    ("media: free flight and boundary crossings", "path.py", "travel_media"),
    ("media: scattering and light samples in media", "path.py", "scatter_in_media"),
    ("media: shadow-ray transmittance", "path.py", "shadow_transmittance"),
    ("textures: albedo at hits", "path.py", "surface_albedo"),
    ("Russian roulette", "path.py", "russian_roulette"),
    ("random numbers (Sampler.pairs, every draw)", "sampling.py", "pairs"),
    ("compaction (PathBatch.take)", "batch.py", "take"),
)


def cumulative(stats: pstats.Stats, suffix: str, func: str) -> float:
    return sum(ct for (file, _line, name), (_cc, _nc, _tt, ct, _callers) in stats.stats.items()
               if file.endswith(suffix) and name == func)


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("scene")
    parser.add_argument("--top", type=int, default=15, help="functions to list by own time")
    args = parser.parse_args(argv)
    scene = wavefront.load_scene(args.scene)
    start = time.perf_counter()
    result = wavefront.render_scene(scene, workers=1)
    wall = time.perf_counter() - start
    profiler = cProfile.Profile()
    profiler.runcall(wavefront.render_scene, scene, workers=1)
    stats = pstats.Stats(profiler)
    total = cumulative(stats, "render.py", "render_scene")
    print(f"{args.scene}: {wall:.2f} s on one core unprofiled, {result.stats.segments:,} path segments "
          f"({wall / result.stats.segments * 1e9:.0f} ns each); {total:.2f} s profiled\n")
    print("| stage | share of the profiled render |\n|---|---|")
    # the BVH's intersect() calls brute force for its outsized primitives: take the outer one
    intersection = max(cumulative(stats, "primitives.py", "intersect"), cumulative(stats, "bvh.py", "intersect"))
    print(f"| intersection (all) | {intersection / total:.0%} |")
    for label, suffix, func in STAGES:
        print(f"| {label} | {cumulative(stats, suffix, func) / total:.0%} |")
    print()
    stats.sort_stats("tottime").print_stats(args.top)


if __name__ == "__main__":
    main()
