"""Per-path costs of random numbers and camera rays, isolated, against another source tree.

    .venv/bin/python benchmarks/sampler_costs.py                       # this tree
    .venv/bin/python benchmarks/sampler_costs.py --compare-tree /work/main --runs 5

What W1's refill and every bounce pay per path: the slots' pixels and sample
ids (``Job.samples``), the sampler's per-path state (``Sampler.start``; a
refill's, as a grid of a unit's pixels and sample indices,
``Sampler.start_grid``, where the tree has it), one pair of uniforms
(``Sampler.pairs``: an int pair in float64, as the camera's were, and a
bounce's, one pair per path in float32, as W1 draws them; the camera's as a
grid, ``Sampler.pairs_grid``, where the tree has it), the camera rays
(``CameraFrame.generate_rays``, W1's camera with defocus) and the whole of
``camera_paths``; in ns per path, at a wavefront of 32 Ki paths of W1's
16-sample passes.  Each tree runs in its own fresh process (cwd = that tree,
so it imports its own ``wavefront``), trees interleaved, ``--runs`` times;
the table gives each figure's minimum over the runs (the machine is shared:
the minimum is the least disturbed run).

A render's heap is warm (freed blocks are reused), a fresh benchmark process's
is not: glibc would return each freed temporary of 128 KiB or more to the
kernel and fault it in again, a third of the time here.  The child therefore
sets glibc's mmap and trim thresholds high first (Linux only), as a render's
steady state has them in effect.
"""

from __future__ import annotations

import argparse
import collections
import json
import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
CHILD = r"""
import ctypes, json, statistics, sys, time
try:  # a warm heap: no page faults per temporary (see the module docstring)
    libc = ctypes.CDLL("libc.so.6")
    libc.mallopt(-3, 64 << 20)  # M_MMAP_THRESHOLD
    libc.mallopt(-1, 256 << 20)  # M_TRIM_THRESHOLD
except OSError:
    pass
import numpy as np
import wavefront
from wavefront.path import camera_paths, render_sampler
from wavefront.sampling import bounce_dimension, scene_key
from wavefront.units import Job, plan_units

N = 1 << 15
scene = wavefront.load_scene("scenes/three_spheres.yaml")
cs = scene.compile()
plan = plan_units(scene.width, scene.height, scene.render.samples_per_pixel)
job = Job([plan[i] for i in range(150, 170)], scene.width, scene.render.samples_per_pixel)  # 16-sample passes
frame = scene.camera.frame(scene.width, scene.height)
sampler = render_sampler(cs, scene_key(1))
pixel, sample_id = job.samples(1000, 1000 + N)
state = sampler.start(pixel, sample_id)
u = np.concatenate((sampler.pairs(state, 0), sampler.pairs(state, 1)))
pair = bounce_dimension(np.random.default_rng(0).integers(0, 5, N).astype(np.int32))

def ns(f, reps=40):
    times = []
    for _ in range(reps):
        t0 = time.perf_counter()
        f()
        times.append(time.perf_counter() - t0)
    return statistics.median(times) / N * 1e9

figures = {
    "Job.samples": ns(lambda: job.samples(1000, 1000 + N)),
    "Sampler.start": ns(lambda: sampler.start(pixel, sample_id)),
    "pairs: camera (int, float64)": ns(lambda: sampler.pairs(state, 0)),
    "pairs: bounce (per path, float32)": ns(lambda: sampler.pairs(state, pair, np.float32)),
    "generate_rays (defocus)": ns(lambda: frame.generate_rays(pixel, u)),
    "camera_paths": ns(lambda: camera_paths(cs, frame, sampler, job, 1000, 1000 + N)),
}
if hasattr(sampler, "start_grid"):  # a refill's grids (trees since session 11)
    block = max(job.blocks(1000, 1000 + N), key=lambda b: b.size)
    grid = sampler.start_grid(block.pixel, block.sample_start, block.sample_stop)
    per_path = N / grid.size  # ns() divides by N
    figures["Sampler.start_grid"] = per_path * ns(lambda: sampler.start_grid(block.pixel, block.sample_start,
                                                                              block.sample_stop))
    figures["pairs_grid: camera (float64)"] = per_path * ns(lambda: sampler.pairs_grid(grid, 0))
print(json.dumps(figures))
"""


def run(tree: str) -> dict:
    env = dict(os.environ, PYTHONPATH=tree)
    out = subprocess.run([sys.executable, "-c", CHILD], capture_output=True, text=True, cwd=tree, env=env, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--compare-tree", help="another source tree (a checkout or worktree) to measure interleaved")
    parser.add_argument("--runs", type=int, default=3)
    args = parser.parse_args(argv)
    trees = [("this tree", str(ROOT))] + ([("other tree", args.compare_tree)] if args.compare_tree else [])
    figures = collections.defaultdict(lambda: collections.defaultdict(list))
    for _ in range(args.runs):
        for label, tree in trees:
            for name, value in run(tree).items():
                figures[name][label].append(value)
    print(f"| ns per path (min of {args.runs}) | " + " | ".join(label for label, _ in trees) + " |")
    print("|---|" + "---|" * len(trees))
    for name, by_tree in figures.items():
        print(f"| {name} | " + " | ".join(f"{min(by_tree[label]):.1f}" if by_tree[label] else "-"
                                          for label, _ in trees) + " |")


if __name__ == "__main__":
    main()
