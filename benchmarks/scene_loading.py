"""Time and peak memory of ``load_scene`` on the cover scene and on large generated scenes.

    .venv/bin/python benchmarks/scene_loading.py                    # 487, 200,000, 1,000,000 spheres
    .venv/bin/python benchmarks/scene_loading.py --spheres 200000   # one size
    .venv/bin/python benchmarks/scene_loading.py --package /tmp/old # another checkout's wavefront

A large scene is the cover scene's header and materials followed by ``N``
small spheres on a grid, each written as ``make_final_scene.py`` writes them
(flow style, ~70 bytes a sphere) and using one of the cover's materials.
Each load runs in a fresh process; peak memory is that process's maximum
resident set (``ru_maxrss``), which includes the interpreter and NumPy
(~30 MiB) and the file's bytes.  Nothing is asserted.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import textwrap
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
COVER = ROOT / "scenes" / "final_scene.yaml"

CHILD = textwrap.dedent("""
    import json, resource, sys, time
    sys.path.insert(0, sys.argv[2])
    t0 = time.perf_counter()
    from wavefront import load_scene
    t1 = time.perf_counter()
    try:
        scene = load_scene(sys.argv[1])
        outcome = f"{len(scene.spheres)} spheres"
    except Exception as e:
        outcome = f"{type(e).__name__}: {str(e)[:200]}"
    t2 = time.perf_counter()
    print(json.dumps({"load_s": t2 - t1, "peak_mib": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
                      "outcome": outcome}))
""")


def write_large_scene(path: Path, spheres: int, seed: int = 1) -> None:
    """The cover scene's header and materials, then ``spheres`` small spheres."""
    header, _, _ = COVER.read_text().partition("spheres:\n")
    names = [line.split(":")[0].strip() for line in header.split("materials:\n", 1)[1].splitlines()]
    rng = np.random.default_rng(seed)
    side = int(np.ceil(np.sqrt(spheres)))
    with open(path, "w") as f:
        f.write(header)
        f.write("spheres:\n  - {center: [0, -1000, 0], radius: 1000, material: ground}\n")
        done = 1
        while done < spheres:
            n = min(100_000, spheres - done)
            i = np.arange(done, done + n)
            x = (i % side - side / 2) + 0.9 * rng.random(n)
            z = (i // side - side / 2) + 0.9 * rng.random(n)
            material = rng.integers(1, len(names), n)
            f.writelines(f"  - {{center: [{a:.6g}, 0.2, {b:.6g}], radius: 0.2, material: {names[m]}}}\n"
                         for a, b, m in zip(x, z, material))
            done += n


def measure(scene: Path, package: Path) -> dict:
    out = subprocess.run([sys.executable, "-c", CHILD, str(scene), str(package)],
                         capture_output=True, text=True, check=True)
    return json.loads(out.stdout)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--spheres", type=int, action="append", help="sizes to generate (default 200000 and 1000000)")
    parser.add_argument("--package", type=Path, default=ROOT, help="directory holding the wavefront package to time")
    args = parser.parse_args()
    sizes = args.spheres or [200_000, 1_000_000]
    print(f"{'scene':>24}  {'MB':>6}  {'load s':>7}  {'peak MiB':>8}  outcome")
    with tempfile.TemporaryDirectory() as tmp:
        scenes = [COVER]
        for n in sizes:
            path = Path(tmp) / f"spheres_{n}.yaml"
            write_large_scene(path, n)
            scenes.append(path)
        for scene in scenes:
            r = measure(scene, args.package)
            print(f"{scene.name:>24}  {os.path.getsize(scene) / 1e6:6.1f}  {r['load_s']:7.2f}  "
                  f"{r['peak_mib']:8.0f}  {r['outcome']}", flush=True)


if __name__ == "__main__":
    main()
