"""W1 and W2 rendered by two source trees in the same run, interleaved.

    git worktree add --detach /tmp/old b747a70      # the tree to compare with
    .venv/bin/python benchmarks/compare_trees.py /tmp/old --runs 3

Each run is a fresh process that imports ``wavefront`` from the tree named
(``PYTHONPATH``), loads the scene and times ``render_scene`` on both cores
(compile and BVH included, as the workloads section).  This checkout runs
twice: with its defaults, and with roulette off and the independent
sampler, the estimator of trees older than light sampling and the sobol
sampler (the same numbers, so the same paths: what is left is the engine's
speed).  Issue #11's floor ("W1 and W2 no slower than before") is read from
it.  Prints medians.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
CHILD = r"""
import dataclasses, json, sys
import wavefront
args = json.loads(sys.argv[1])
scene = wavefront.load_scene(args["scene"])
if args["old_estimator"]:  # the estimator of trees older than light sampling and the sobol sampler
    scene = scene.replace(render=dataclasses.replace(scene.render, russian_roulette=None, sampler="independent"))
r = wavefront.render_scene(scene, workers=2)
print(json.dumps({"elapsed": r.stats.elapsed}))
"""
SCENES = (("W1", "scenes/three_spheres.yaml"), ("W2", "scenes/final_scene.yaml"))


def run(tree: str, scene: str, old_estimator: bool) -> float:
    env = dict(os.environ, PYTHONPATH=tree)
    out = subprocess.run([sys.executable, "-c", CHILD, json.dumps({"scene": scene, "old_estimator": old_estimator})],
                         capture_output=True, text=True, cwd=tree, env=env, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])["elapsed"]


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("other", help="the other source tree (a checkout or worktree)")
    parser.add_argument("--runs", type=int, default=3)
    args = parser.parse_args(argv)
    variants = (("other tree", args.other, False), ("this tree", str(ROOT), False),
                ("this tree, no roulette, independent sampler", str(ROOT), True))
    times = {}
    for _ in range(args.runs):
        for name, scene in SCENES:
            for label, tree, old_estimator in variants:
                times.setdefault((name, label), []).append(run(tree, scene, old_estimator))
    print(f"| workload | tree | median of {args.runs} | runs |\n|---|---|---|---|")
    for (name, label), values in times.items():
        print(f"| {name} | {label} | {statistics.median(values):.2f} s | "
              f"{', '.join(f'{v:.2f}' for v in values)} |")


if __name__ == "__main__":
    main()
