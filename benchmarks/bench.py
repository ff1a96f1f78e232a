"""wavefront benchmarks: time, throughput and peak memory, against baselines measured in the same run.

    make bench                                 # everything, as quoted in the README
    .venv/bin/python benchmarks/bench.py --section workloads --runs 5

Sections
--------
workloads  W1 (three_spheres, 400x225, 100 spp) and W2 (final_scene, ~487
           spheres, 400x225, 10 spp), both max_depth 50, with wavefront on all
           cores and with Mitsuba 3 (``llvm_ad_rgb`` if Dr.Jit finds LLVM, else
           ``scalar_rgb``, said in the output) on the same scene, built by
           ``benchmarks/mitsuba_scene.py``.  Medians of ``--runs`` runs, each in
           a fresh process; Mitsuba gets one unmeasured warm-up render per
           process so its JIT compilation is not counted.  Mitsuba runs twice:
           as it comes (the baseline; Russian roulette from depth 5) and with
           rr_depth past max_depth, the estimator wavefront runs.
whole_process  W1 and W2 as a user runs them: ``wavefront render`` from launch
           to PNG on disk against Mitsuba 3 from ``python`` launch to EXR on
           disk (import, the scene from a JSON dict written beforehand, Dr.Jit's
           cached kernels, render, write); medians of ``--runs`` interleaved
           runs after a warm-up, beside the in-process figures (wavefront's
           ``render_scene`` in a fresh process, Mitsuba's second render).
           W3, the cover at 1200x675 and 500 spp, one run each, comes last
           (several minutes; ``--no-w3`` leaves it out, ``--w3-size
           120x68x2`` checks its set-up quickly).
startup    every fixed cost of one ``wavefront render`` (the 40x23, 1 spp
           cover and W2): interpreter start, imports, arguments, YAML,
           validation, compile, BVH, pool start, render, encode, PNG write,
           interpreter exit, each part's median and share; imports by package
           from ``python -X importtime``.  ``--compare-tree DIR`` measures
           another source tree (``git archive COMMIT wavefront | tar -x -C DIR``)
           interleaved with this one, for before/after figures.
scaling    time per path segment for 10, 100, 1,000 and 10,000 random spheres
           (one core), with the brute-force intersector as the baseline where
           it finishes in reasonable time.
memory     peak memory of 3840x2160 renders at 1 and 4 samples per pixel next
           to a 400x225 one: buffers come from the budget, not the image.
budget     ``wavefront render`` under ``--memory 256M`` and ``1G`` (W2, 4K,
           8K, 200,000 spheres), the whole process tree's peak resident
           memory polled from outside next to the peak the summary reports.
capacity   W1 at 20 spp on one core for several wavefront sizes.
next_week  book 2's final scene (scenes/next_week_final.yaml, 400x400, 10
           spp: textures, a moving sphere, fog) on all cores, and Mitsuba 3's
           ``volpath`` on the comparable scene (flat colours, the sphere still
           at mid-shutter, ``homogeneous`` media).
geometry   the Cornell box (RTOW book 3, 128x128, 64 spp) and a generated
           ~1M-triangle terrain mesh (128x128, 16 spp) with wavefront on all
           cores and Mitsuba 3 on the same scenes (``rectangle`` and ``ply``
           shapes, one-sided ``area`` emitters); the BVH build time at 1M
           triangles on one core; time per path segment at 1M against 1k
           triangles of the same surface (one core, build excluded), and of
           the rough terrains (per-vertex noise: a stress case whose surface
           changes with the count); peak memory of the 1M render.
equal_error  noise per second: the Cornell box and scenes/cornell_spheres.yaml
           (128x128, max_depth 50) rendered by wavefront (light sampling and
           roulette on, its defaults) and by Mitsuba 3's ``path`` integrator
           (same max depth, its default roulette from depth 5) at several
           sample counts; each image's MSE against that renderer's own
           converged image (rendered once, cached in benchmarks/references/
           as float16 .npy), so differences between the two material models
           do not count as noise; the efficiency ratio
           ``(time_wavefront * MSE_wavefront) / (time_mitsuba * MSE_mitsuba)``
           (median of runs; below 1, wavefront is ahead) against Mitsuba's
           default ``independent`` sampler and its stratified ``multijitter``
           and ``ldsampler``; wavefront's ``sobol`` (default) against its
           ``independent`` sampler; light sampling on against off.
distributed  the final scene on Dask LocalClusters of 1 and 2 workers against
           the plain local render (1 and 2 processes), and Dask's overhead per
           task (cluster start-up excluded, one warm-up render each).

Every number is measured by this script in the run that prints it; nothing is
asserted.  Tables go to stdout and to ``benchmarks/results/``, with a plot of
the scaling table.
"""

from __future__ import annotations

import argparse
import glob
import json
import os
import statistics
import subprocess
import sys
import textwrap
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
RESULTS = ROOT / "benchmarks" / "results"
PYTHON = sys.executable

# --- helpers run in child processes -----------------------------------------

WAVEFRONT_CHILD = textwrap.dedent("""
    import json, sys
    import wavefront, wavefront.accel as accel
    args = json.loads(sys.argv[1])
    if args.get("brute_force"):
        accel.BVH_THRESHOLD = 1 << 62
    scene = wavefront.load_scene(args["scene"]) if "scene" in args else None
    if "random_spheres" in args:
        sys.path.insert(0, args["bench_dir"])
        from bench import random_sphere_scene
        scene = random_sphere_scene(args["random_spheres"])
    scene = scene.with_overrides(**args.get("overrides", {}))
    r = wavefront.render_scene(scene, workers=args.get("workers"), chunk_size=args.get("chunk_size"))
    s = r.stats
    print(json.dumps({"elapsed": s.elapsed, "samples": s.samples, "segments": s.segments,
                      "peak": s.peak_memory, "workers": s.workers}))
""")

MITSUBA_CHILD = textwrap.dedent("""
    import json, resource, sys, time
    args = json.loads(sys.argv[1])
    import numpy as np, mitsuba as mi
    mi.set_variant(args["variant"])
    sys.path.insert(0, args["bench_dir"])
    from mitsuba_scene import mitsuba_scene_dict
    import wavefront
    scene = wavefront.load_scene(args["scene"])
    scene = scene.with_overrides(**args.get("overrides", {}))
    import tempfile
    mscene = mi.load_dict(mitsuba_scene_dict(scene, mi, russian_roulette=not args.get("no_rr"),
                                             workdir=tempfile.mkdtemp()))
    spp = scene.render.samples_per_pixel
    np.array(mi.render(mscene, spp=spp))  # warm-up: JIT compilation is not timed
    t = time.perf_counter()
    image = np.array(mi.render(mscene, spp=spp))
    elapsed = time.perf_counter() - t
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
    print(json.dumps({"elapsed": elapsed, "samples": scene.width * scene.height * spp, "peak": peak,
                      "mean": float(image.mean())}))
""")


def child(code: str, args: dict, env=None) -> dict:
    out = subprocess.run([PYTHON, "-c", code, json.dumps(args)], capture_output=True, text=True,
                         cwd=ROOT, env=env, timeout=3600)
    if out.returncode != 0:
        raise RuntimeError(out.stderr.strip().splitlines()[-1] if out.stderr.strip() else "child failed")
    return json.loads(out.stdout.strip().splitlines()[-1])


def median_runs(code, args, runs, env=None) -> dict:
    results = [child(code, args, env) for _ in range(runs)]
    keys = [k for k in results[0] if isinstance(results[0][k], (int, float))]
    return {k: statistics.median(r[k] for r in results) for k in keys}


def find_llvm() -> str | None:
    if os.environ.get("DRJIT_LIBLLVM_PATH"):
        return os.environ["DRJIT_LIBLLVM_PATH"]
    for pattern in ("/usr/lib/*/libLLVM-19.so*", "/usr/lib/llvm-19/lib/libLLVM*.so*", "/usr/lib/*/libLLVM.so.19*",
                    "/usr/lib/*/libLLVM-1[5-9].so"):
        found = sorted(glob.glob(pattern))
        if found:
            return found[0]
    return None


def mitsuba_setup():
    """(variant, env, note) or (None, None, reason)."""
    try:
        import mitsuba  # noqa: F401
    except ImportError:
        return None, None, "Mitsuba 3 is not installed (pip install -e '.[bench]')"
    env = dict(os.environ)
    llvm = find_llvm()
    if llvm:
        env["DRJIT_LIBLLVM_PATH"] = llvm
        try:
            # a tiny render, not just set_variant: an LLVM older than Dr.Jit expects loads but fails to compile
            child("import mitsuba as mi; mi.set_variant('llvm_ad_rgb'); d = mi.cornell_box(); "
                  "d['sensor']['film'].update(width=8, height=8); mi.render(mi.load_dict(d), spp=1); print('{}')",
                  {}, env)
            return "llvm_ad_rgb", env, f"Mitsuba 3 llvm_ad_rgb (LLVM: {llvm})"
        except RuntimeError as e:
            reason = f"llvm_ad_rgb failed ({e})"
    else:
        reason = "no libLLVM found (apt-get install libllvm19)"
    return "scalar_rgb", env, f"Mitsuba 3 scalar_rgb, because {reason}"


# --- scenes -------------------------------------------------------------------

def random_sphere_scene(count: int, seed: int = 7):
    """``count`` small spheres on a ground, at constant density, viewed from above at an angle."""
    import numpy as np

    from wavefront import Camera, Dielectric, Lambertian, Metal, Scene, Sky, Sphere

    rng = np.random.default_rng(seed)
    half = 0.75 * np.sqrt(count)  # ~0.44 spheres per unit area at any count
    materials = {"ground": Lambertian((0.5, 0.5, 0.5)), "matte": Lambertian((0.6, 0.3, 0.2)),
                 "metal": Metal((0.8, 0.8, 0.8), 0.2), "glass": Dielectric(1.5)}
    kinds = rng.choice(["matte", "metal", "glass"], size=count, p=[0.8, 0.15, 0.05])
    xz = rng.uniform(-half, half, (count, 2))
    spheres = [Sphere((0.0, -1000.0, 0.0), 1000.0, "ground")]
    spheres += [Sphere((float(x), 0.2, float(z)), 0.2, str(k)) for (x, z), k in zip(xz, kinds)]
    camera = Camera(look_from=(0.0, 1.2 * half + 1, 1.6 * half + 2), look_at=(0.0, 0.0, 0.0), vfov=45)
    return Scene(spheres=spheres, materials=materials, camera=camera, background=Sky(), name=f"random{count}")


# --- sections -----------------------------------------------------------------

def fmt_mib(b):
    return f"{b / 2**20:.0f} MiB"


def table(header, rows):
    widths = [max(len(str(x)) for x in col) for col in zip(header, *rows)]
    line = lambda r: "| " + " | ".join(str(x).ljust(w) for x, w in zip(r, widths)) + " |"  # noqa: E731
    return "\n".join([line(header), "|" + "|".join("-" * (w + 2) for w in widths) + "|", *map(line, rows)])


def section_workloads(runs):
    variant, env, note = mitsuba_setup()
    rows, data = [], {}
    for name, scene in (("W1", "scenes/three_spheres.yaml"), ("W2", "scenes/final_scene.yaml")):
        w = median_runs(WAVEFRONT_CHILD, {"scene": scene}, runs)
        data[name] = {"wavefront": w}
        row = [name, f"wavefront ({int(w['workers'])} workers)", f"{w['elapsed']:.2f} s",
               f"{w['samples'] / w['elapsed'] / 1e6:.2f} M", f"{w['segments'] / w['elapsed'] / 1e6:.2f} M",
               fmt_mib(w["peak"])]
        if variant:
            m = median_runs(MITSUBA_CHILD, {"scene": scene, "variant": variant,
                                            "bench_dir": str(ROOT / "benchmarks")}, runs, env)
            data[name]["mitsuba"] = m
            rows.append(row + [f"{w['elapsed'] / m['elapsed']:.2f}x"])
            rows.append([name, variant, f"{m['elapsed']:.2f} s", f"{m['samples'] / m['elapsed'] / 1e6:.2f} M",
                         "–", fmt_mib(m["peak"]), "1.00x"])
            # the same estimator as wavefront's: no Russian roulette (shown, not the baseline)
            q = median_runs(MITSUBA_CHILD, {"scene": scene, "variant": variant, "no_rr": True,
                                            "bench_dir": str(ROOT / "benchmarks")}, runs, env)
            data[name]["mitsuba_no_rr"] = q
            rows.append([name, f"{variant}, no Russian roulette", f"{q['elapsed']:.2f} s",
                         f"{q['samples'] / q['elapsed'] / 1e6:.2f} M", "–", fmt_mib(q["peak"]),
                         f"{q['elapsed'] / m['elapsed']:.2f}x"])
        else:
            rows.append(row + ["–"])
    text = table(["workload", "renderer", "wall time", "samples/s", "path segments/s", "peak memory",
                  "time / Mitsuba"], rows)
    return (f"Baseline: {note}, its default path integrator (Russian roulette from depth 5). The "
            f"row without Russian roulette (rr_depth past max_depth) runs the estimator wavefront runs; "
            f"its last column is relative to the baseline. Medians of {runs} runs, each in a fresh "
            f"process.\n\n{text}"), data


def section_scaling(runs):
    counts = (10, 100, 1000, 10000)
    overrides = {"width": 160, "height": 90, "samples_per_pixel": 16}
    rows, data = [], {}
    for n in counts:
        args = {"random_spheres": n, "bench_dir": str(ROOT / "benchmarks"), "overrides": overrides, "workers": 1}
        bvh = median_runs(WAVEFRONT_CHILD, args, runs)
        per = bvh["elapsed"] / bvh["segments"] * 1e9
        entry = {"auto_ns_per_segment": per}
        brute_txt = "–"
        if n <= 1000:
            brute = median_runs(WAVEFRONT_CHILD, dict(args, brute_force=True), runs)
            entry["brute_ns_per_segment"] = brute["elapsed"] / brute["segments"] * 1e9
            brute_txt = f"{entry['brute_ns_per_segment']:.0f} ns"
        data[n] = entry
        rows.append([f"{n:,}", "brute force" if n < 64 else "BVH", f"{per:.0f} ns", brute_txt])
    ratio = data[10000]["auto_ns_per_segment"] / data[100]["auto_ns_per_segment"]
    text = table(["spheres", "intersector chosen", "time per path segment", "brute force (baseline)"], rows)
    text += f"\n\nTime per segment at 10,000 spheres / at 100 spheres: {ratio:.2f}x"
    data["ratio_10000_100"] = ratio
    return ("One core, 160x90, 16 spp, max_depth 50, spheres of radius 0.2 at constant density on a ground "
            f"sphere; medians of {runs} runs; each time includes building the scene (and its BVH).\n\n{text}"), data


def section_memory(runs):
    rows, data = [], {}
    for label, overrides in (("400x225, 4 spp", {"width": 400, "height": 225, "samples_per_pixel": 4}),
                             ("3840x2160, 1 spp", {"width": 3840, "height": 2160, "samples_per_pixel": 1}),
                             ("3840x2160, 4 spp", {"width": 3840, "height": 2160, "samples_per_pixel": 4})):
        r = median_runs(WAVEFRONT_CHILD, {"scene": "scenes/three_spheres.yaml", "overrides": overrides}, 1)
        data[label] = r
        rows.append([label, f"{r['elapsed']:.1f} s", fmt_mib(r["peak"])])
    text = table(["render (three_spheres, all cores)", "wall time", "peak memory"], rows)
    return ("Peak memory is the parent's peak resident set plus each worker's (an upper bound: "
            f"shared pages count twice).\n\n{text}"), data


def section_capacity(runs):
    rows, data = [], {}
    for capacity in (4096, 16384, 65536, 262144):
        r = median_runs(WAVEFRONT_CHILD, {"scene": "scenes/three_spheres.yaml", "workers": 1,
                                          "chunk_size": capacity, "overrides": {"samples_per_pixel": 20}}, runs)
        data[capacity] = r
        rows.append([f"{capacity:,}", f"{r['elapsed']:.2f} s", f"{r['segments'] / r['elapsed'] / 1e6:.2f} M",
                     fmt_mib(r["peak"])])
    text = table(["paths in flight", "wall time", "path segments/s", "peak memory"], rows)
    return f"W1 at 20 spp on one core; medians of {runs} runs.\n\n{text}", data


MESH_CHILD = textwrap.dedent("""
    import json, sys, time
    import wavefront
    args = json.loads(sys.argv[1])
    scene = wavefront.load_scene(args["scene"]).with_overrides(**args.get("overrides", {}))
    triangles = sum(len(m) for m in scene.meshes) + len(scene.triangles)
    start = time.perf_counter()
    compiled = scene.compile()  # the BVH build, timed on its own
    build = time.perf_counter() - start
    if args.get("reuse"):  # the render alone: per-segment times are not a difference of two noisy timings
        r = wavefront.render_scene(scene, workers=args.get("workers"), memory=args.get("memory", 1 << 30),
                                   compiled=compiled)
    else:
        del compiled
        r = wavefront.render_scene(scene, workers=args.get("workers"), memory=args.get("memory", 1 << 30))
    s = r.stats
    print(json.dumps({"elapsed": s.elapsed, "build": build, "samples": s.samples, "segments": s.segments,
                      "peak": s.peak_memory, "workers": s.workers, "triangles": triangles}))
""")

# The one-core mesh benchmarks' scene (bench.py's terrains, terrain_segments.py's torus too)
MESH_SCENE = """\
# generated by benchmarks/{script}: {what} under the sky
image: {{width: 128, height: 128}}
camera: {camera}
render: {{samples_per_pixel: 16, max_depth: 50, seed: 1}}
background: {{type: sky}}
materials: {{ground: {{type: lambertian, albedo: [0.6, 0.5, 0.4]}}}}
meshes: [{{file: {file}, material: ground}}]
"""


TERRAIN_CAMERA = "{look_from: [0, 1.6, 2.4], look_at: [0, 0, 0], vfov: 40}"


def terrain_scene(folder: Path, triangles: int, rough: bool = False) -> str:
    """A scene file around a generated terrain mesh (scenes/make_mesh_models.py's
    ``terrain``: the same surface at every triangle count, or with ``rough`` the
    per-vertex noise whose slopes grow with the count, a stress case)."""
    name = f"{'rough_' if rough else ''}terrain_{triangles}"
    ply = folder / f"{name}.ply"
    subprocess.run([PYTHON, str(ROOT / "scenes" / "make_mesh_models.py"), "--big", str(ply),
                    "--triangles", str(triangles)] + (["--rough"] if rough else []), check=True, timeout=600)
    path = folder / f"{name}.yaml"
    path.write_text(MESH_SCENE.format(script="bench.py", what=f"a {'rough' if rough else 'bumpy'} terrain of {triangles} "
                                      "triangles", camera=TERRAIN_CAMERA, file=ply.name))
    return str(path)


def section_geometry(runs):
    import tempfile

    variant, env, note = mitsuba_setup()
    folder = Path(tempfile.mkdtemp(prefix="wavefront-bench-"))
    big, small = terrain_scene(folder, 1_000_000), terrain_scene(folder, 1_000)
    rows, data = [], {}
    cornell = {"scene": "scenes/cornell_box.yaml", "overrides": {"width": 128, "height": 128, "samples_per_pixel": 64}}
    # the floor for the 1M-triangle render is 1.5 GB: that is its budget (the default 1 GiB is too small)
    terrain = {"scene": big, "memory": 1536 << 20}
    for name, args in (("Cornell box 128x128, 64 spp", cornell), ("terrain, ~1M triangles, 128x128, 16 spp",
                                                                  terrain)):
        w = median_runs(MESH_CHILD, args, runs)
        data[name] = {"wavefront": w}
        row = [name, f"wavefront ({int(w['workers'])} workers)", f"{w['elapsed']:.2f} s",
               f"{w['segments'] / w['elapsed'] / 1e6:.2f} M", fmt_mib(w["peak"])]
        if variant:
            m = median_runs(MITSUBA_CHILD, dict(args, variant=variant, bench_dir=str(ROOT / "benchmarks")), runs, env)
            data[name]["mitsuba"] = m
            rows.append(row + [f"{w['elapsed'] / m['elapsed']:.2f}x"])
            rows.append([name, variant, f"{m['elapsed']:.2f} s", "–", fmt_mib(m["peak"]), "1.00x"])
        else:
            rows.append(row + ["–"])
    text = table(["scene", "renderer", "wall time", "path segments/s", "peak memory", "time / Mitsuba"], rows)
    # One core: the build, and the time per segment with the build taken out.  The floor's
    # pair is one surface cut into ~1M and ~1k triangles; the rough pair (per-vertex noise,
    # the benchmark's terrain up to session 7) is a different surface at each size, kept as
    # the BVH's stress case (sub-pixel spikes at 1M).
    one = {}
    for label, scene in (("1M", big), ("1k", small), ("1M rough", terrain_scene(folder, 1_000_000, rough=True)),
                         ("1k rough", terrain_scene(folder, 1_000, rough=True))):
        r = median_runs(MESH_CHILD, {"scene": scene, "workers": 1, "memory": 1536 << 20, "reuse": True}, runs)
        r["ns_per_segment"] = r["elapsed"] / r["segments"] * 1e9  # the render of the compiled scene alone
        one[label] = r
    data["one_core"] = one
    ratio = one["1M"]["ns_per_segment"] / one["1k"]["ns_per_segment"]
    rough_ratio = one["1M rough"]["ns_per_segment"] / one["1k rough"]["ns_per_segment"]
    data["segment_ratio_1M_1k"] = ratio
    data["segment_ratio_rough"] = rough_ratio
    text += "\n\n" + table(
        ["terrain, one core", "triangles", "scene compile + BVH build", "time per path segment",
         "segments per path", "peak memory"],
        [[label, f"{int(r['triangles']):,}", f"{r['build']:.2f} s", f"{r['ns_per_segment']:.0f} ns",
          f"{r['segments'] / r['samples']:.2f}", fmt_mib(r["peak"])] for label, r in one.items()])
    text += (f"\n\nTime per segment at 1M triangles / at 1k triangles (the same surface): {ratio:.2f}x; "
             f"rough terrains (a different surface at each size): {rough_ratio:.2f}x")
    return (f"Baseline: {note}, its default path integrator. Medians of {runs} runs, each in a fresh process; "
            "wall times include loading the scene and building the BVH (the terrain is written once, by "
            f"scenes/make_mesh_models.py).\n\n{text}"), data


DASK_CHILD = textwrap.dedent("""
    import json, sys, time
    import wavefront
    from wavefront.render import plan_tasks
    from wavefront.units import plan_units
    args = json.loads(sys.argv[1])
    scene = wavefront.load_scene(args["scene"]).with_overrides(**args.get("overrides", {}))
    n = args["workers"]
    executor = None
    if args["dask"]:
        from dask.distributed import Client, LocalCluster
        from wavefront.distributed import dask_executor
        cluster = LocalCluster(n_workers=n, threads_per_worker=1, processes=True, dashboard_address=None,
                               silence_logs=50)
        client = Client(cluster)
        executor = dask_executor(client)
    r = wavefront.render_scene(scene, workers=n, executor=executor)  # warm-up
    times = []
    for _ in range(args["runs"]):
        r = wavefront.render_scene(scene, workers=n, executor=executor)
        times.append(r.stats.elapsed)
    units = plan_units(scene.width, scene.height, scene.render.samples_per_pixel)
    tasks = sum(1 for _ in plan_tasks(units, r.stats.capacity, n))
    times.sort()
    print(json.dumps({"elapsed": times[len(times) // 2], "tasks": tasks, "units": len(units)}))
""")


EQUAL_WAVEFRONT_CHILD = textwrap.dedent("""
    import json, sys, time
    import numpy as np
    import dataclasses, wavefront
    args = json.loads(sys.argv[1])
    scene = wavefront.load_scene(args["scene"]).with_overrides(**args["overrides"])
    scene = scene.replace(render=dataclasses.replace(scene.render, **args.get("settings", {})))
    # Twice, the same image: the first render in a fresh process also pays
    # one-time costs (first imports, first calls); the second is timed as
    # Mitsuba's render is, after its warm-up (which compiles its kernels).
    first = wavefront.render_scene(scene, workers=args.get("workers")) if args.get("twice", True) else None
    r = wavefront.render_scene(scene, workers=args.get("workers"))
    assert first is None or np.array_equal(first.image, r.image)
    np.save(args["out"], r.image)
    print(json.dumps({"elapsed": r.stats.elapsed, "first": first and first.stats.elapsed,
                      "segments": r.stats.segments}))
""")

EQUAL_MITSUBA_CHILD = textwrap.dedent("""
    import json, sys, time, tempfile
    import numpy as np, mitsuba as mi
    args = json.loads(sys.argv[1])
    mi.set_variant(args["variant"])
    sys.path.insert(0, args["bench_dir"])
    from mitsuba_scene import mitsuba_scene_dict
    import wavefront
    scene = wavefront.load_scene(args["scene"]).with_overrides(**args["overrides"])
    spec = mitsuba_scene_dict(scene, mi, workdir=tempfile.mkdtemp())
    spec["sensor"]["sampler"]["type"] = args.get("sampler", "independent")
    mscene = mi.load_dict(spec)
    spp = scene.render.samples_per_pixel
    np.array(mi.render(mscene, spp=min(spp, 16), seed=10**6))  # warm-up: JIT compilation is not timed
    # at most 1024 spp per call: one llvm_ad_rgb wavefront of 128x128x16384 samples fails to compile
    passes = [min(1024, spp - k) for k in range(0, spp, 1024)]
    t = time.perf_counter()
    image = sum(np.array(mi.render(mscene, spp=n, seed=scene.render.seed * 1000 + k)) * n
                for k, n in enumerate(passes)) / spp
    elapsed = time.perf_counter() - t
    np.save(args["out"], image)
    print(json.dumps({"elapsed": elapsed}))
""")

EQUAL_ERROR_SCENES = (("Cornell box", "scenes/cornell_box.yaml"), ("Cornell spheres", "scenes/cornell_spheres.yaml"))
EQUAL_ERROR_SIZE = 128
EQUAL_ERROR_SPP = (4, 16, 64)
# Mitsuba's stratified samplers, beside its default ``independent`` (the
# floor's baseline): ``multijitter`` (correlated multi-jittered, Kensler 2013)
# and ``ldsampler`` (a scrambled (0, 2)-sequence per pair of dimensions, the
# closest to wavefront's sobol).  All share Mitsuba's one converged reference.
MITSUBA_STRATIFIED = ("multijitter", "ldsampler")
# Reference sample counts: far above the largest measured count (64), so a
# reference's own error adds at most ~1/32 (wavefront) or ~1/256 (Mitsuba) to a
# measured MSE.  cornell_spheres' wavefront reference has 2048 (time on the
# shared 2-core machine).
REFERENCE_SPP = {"wavefront": 4096, "mitsuba": 16384}
REFERENCE_SPP_OF_SCENE = {"scenes/cornell_spheres.yaml": {"wavefront": 2048}}
REFERENCES = ROOT / "benchmarks" / "references"


def section_next_week(runs):
    """Book 2's final scene (textures, motion blur, media) against Mitsuba's
    comparable scene (flat colours, the sphere still at mid-shutter,
    ``homogeneous`` media, ``volpath``); issue #13's floor is 2x."""
    variant, env, note = mitsuba_setup()
    args = {"scene": "scenes/next_week_final.yaml"}
    w = median_runs(WAVEFRONT_CHILD, args, runs)
    rows = [["next_week_final 400x400, 10 spp", f"wavefront ({int(w['workers'])} workers)", f"{w['elapsed']:.2f} s",
             f"{w['segments'] / w['elapsed'] / 1e6:.2f} M", fmt_mib(w["peak"])]]
    data = {"wavefront": w}
    if variant:
        m = median_runs(MITSUBA_CHILD, dict(args, variant=variant, bench_dir=str(ROOT / "benchmarks")), runs, env)
        data["mitsuba"] = m
        rows[0].append(f"{w['elapsed'] / m['elapsed']:.2f}x")
        rows.append(["next_week_final 400x400, 10 spp", f"{variant} (volpath)", f"{m['elapsed']:.2f} s", "–",
                     fmt_mib(m["peak"]), "1.00x"])
    else:
        rows[0].append("–")
    text = table(["scene", "renderer", "wall time", "path segments/s", "peak memory", "time / Mitsuba"], rows)
    return (f"Baseline: {note}, its volpath integrator on the comparable scene (textures as their mean "
            f"colour, the moving sphere still at mid-shutter). Medians of {runs} runs, each in a fresh process; "
            f"wavefront's time includes compiling the scene and its BVH, Mitsuba's is a render after a "
            f"warm-up.\n\n{text}"), data


def _mse(image_path, reference):
    import numpy as np

    image = np.load(image_path).astype(np.float64)
    return float(((image - reference) ** 2).mean())


def _reference(label, scene, renderer, variant, env, folder):
    """A renderer's own converged image of ``scene``, rendered once and cached."""
    import numpy as np

    REFERENCES.mkdir(parents=True, exist_ok=True)
    spp = REFERENCE_SPP_OF_SCENE.get(scene, {}).get(renderer, REFERENCE_SPP[renderer])
    stem = Path(scene).stem
    # wavefront's with its sobol sampler: at 4096 spp its own error is far below
    # the sobol images' it measures (independent numbers left ~3e-5, a quarter of
    # the Cornell box's MSE at 64 spp)
    kind = variant if renderer == "mitsuba" else "sobol"
    path = REFERENCES / f"{stem}_{EQUAL_ERROR_SIZE}_{renderer}_{kind}_{spp}spp.npy"
    if not path.exists():
        out = folder / f"ref_{stem}_{renderer}.npy"
        overrides = {"width": EQUAL_ERROR_SIZE, "height": EQUAL_ERROR_SIZE, "samples_per_pixel": spp, "seed": 77}
        if renderer == "wavefront":
            child(EQUAL_WAVEFRONT_CHILD, {"scene": scene, "overrides": overrides, "settings": {"sampler": "sobol"},
                                          "out": str(out), "twice": False})
        else:
            child(EQUAL_MITSUBA_CHILD, {"scene": scene, "overrides": overrides, "out": str(out), "variant": variant,
                                        "bench_dir": str(ROOT / "benchmarks")}, env)
        np.save(path, np.load(out).astype(np.float16))  # float16: ~100 KB, far below the noise it measures
        print(f"  cached {path.relative_to(ROOT)} ({label}, {renderer}, {spp} spp)", flush=True)
    return np.load(path).astype(np.float64)


def section_equal_error(runs):
    import tempfile

    variant, env, note = mitsuba_setup()
    folder = Path(tempfile.mkdtemp(prefix="wavefront-equal-error-"))
    rows, sampler_rows, stratified_rows, nee_rows, data = [], [], [], [], {}
    # wavefront's default (sobol), its independent sampler, and light sampling
    # off (the same sampler: the light-sampling gain alone)
    configurations = (("wavefront", {"sampler": "sobol"}), ("independent", {"sampler": "independent"}),
                      ("book", {"light_sampling": False, "russian_roulette": False, "sampler": "sobol"}))
    mitsuba_samplers = ("independent", *MITSUBA_STRATIFIED)

    def efficiency(a, b):
        """Median over runs of (time x MSE) of ``a`` over ``b``'s."""
        return statistics.median(x[0] * x[1] / (y[0] * y[1]) for x, y in zip(a, b))

    for label, scene in EQUAL_ERROR_SCENES:
        ref_wf = _reference(label, scene, "wavefront", variant, env, folder)
        ref_mi = _reference(label, scene, "mitsuba", variant, env, folder) if variant else None
        data[label] = {}
        for spp in EQUAL_ERROR_SPP:
            results = {k: [] for k, _ in configurations}
            results.update({f"mitsuba {s}": [] for s in mitsuba_samplers})
            firsts = []  # wavefront's (sobol) first render in its process: (time, MSE)
            for run in range(runs):
                overrides = {"width": EQUAL_ERROR_SIZE, "height": EQUAL_ERROR_SIZE, "samples_per_pixel": spp,
                             "seed": 1000 + run}
                for key, settings in configurations:
                    out = folder / f"{key}.npy"
                    w = child(EQUAL_WAVEFRONT_CHILD, {"scene": scene, "overrides": overrides, "settings": settings,
                                                      "out": str(out)})
                    results[key].append((w["elapsed"], _mse(out, ref_wf)))
                    if key == "wavefront":
                        firsts.append((w["first"], results[key][-1][1]))
                if variant:
                    for sampler in mitsuba_samplers:
                        out = folder / "mitsuba.npy"
                        m = child(EQUAL_MITSUBA_CHILD, {"scene": scene, "overrides": overrides, "out": str(out),
                                                        "variant": variant, "sampler": sampler,
                                                        "bench_dir": str(ROOT / "benchmarks")}, env)
                        results[f"mitsuba {sampler}"].append((m["elapsed"], _mse(out, ref_mi)))
            med = {k: (statistics.median(t for t, _ in v), statistics.median(e for _, e in v))
                   for k, v in results.items() if v}
            data[label][spp] = {k: {"time": t, "mse": e} for k, (t, e) in med.items()}
            (tw, ew), (ti, ei), (tb, eb) = med["wavefront"], med["independent"], med["book"]
            gain = efficiency(results["independent"], results["wavefront"])
            data[label][spp]["sobol_gain"] = gain
            sampler_rows.append([label, spp, f"{tw:.2f} s", f"{ew:.3g}", f"{ti:.2f} s", f"{ei:.3g}",
                                 f"{ei / ew:.2f}x", f"{gain:.2f}x"])
            if variant:
                tm, em = med["mitsuba independent"]
                ratio = efficiency(results["wavefront"], results["mitsuba independent"])
                ratio_independent = efficiency(results["independent"], results["mitsuba independent"])
                ratio_first = efficiency(firsts, results["mitsuba independent"])
                data[label][spp].update(ratio=ratio, ratio_independent=ratio_independent, ratio_first=ratio_first,
                                        first_time=statistics.median(t for t, _ in firsts))
                rows.append([label, spp, f"{tw:.3f} s", f"{ew:.3g}", f"{tm:.3f} s", f"{em:.3g}", f"{ratio:.2f}",
                             f"{ratio_independent:.2f}", f"{statistics.median(t for t, _ in firsts):.3f} s",
                             f"{ratio_first:.2f}"])
                cells, best = [], None
                for sampler in MITSUBA_STRATIFIED:
                    ts, es = med[f"mitsuba {sampler}"]
                    r = efficiency(results["wavefront"], results[f"mitsuba {sampler}"])
                    data[label][spp][f"ratio_{sampler}"] = r
                    cells += [f"{ts:.2f} s", f"{es:.3g}", f"{r:.2f}"]
                    best = r if best is None else max(best, r)
                stratified_rows.append([label, spp, f"{ew:.3g}", *cells])
            nee = efficiency(results["book"], results["wavefront"])
            data[label][spp]["light_sampling_gain"] = nee
            nee_rows.append([label, spp, f"{tw:.2f} s", f"{ew:.3g}", f"{tb:.2f} s", f"{eb:.3g}", f"{nee:.1f}x"])
    text = ""
    if variant:
        text += table(["scene (128x128)", "spp", "wavefront (sobol) time", "MSE", "Mitsuba (independent) time",
                       "MSE", "efficiency ratio (wf / Mitsuba)", "same, wf independent",
                       "wf's first render in its process: time", "its ratio"], rows) + "\n\n"
        header = ["scene (128x128)", "spp", "wavefront (sobol) MSE"]
        for sampler in MITSUBA_STRATIFIED:
            header += [f"Mitsuba {sampler} time", "MSE", f"ratio (wf / {sampler})"]
        text += table(header, stratified_rows) + "\n\n"
    text += table(["scene (128x128)", "spp", "sobol: time", "MSE", "independent: time", "MSE",
                   "MSE ratio (independent / sobol)", "efficiency gain of sobol"], sampler_rows) + "\n\n"
    text += table(["scene (128x128)", "spp", "light sampling on: time", "MSE", "off (and roulette off): time", "MSE",
                   "efficiency gain of light sampling"], nee_rows)
    return (f"Baseline: {note}, its path integrator (max_depth 50, roulette from depth 5), with its default "
            f"sampler (independent; the floor's ratio) and its stratified ones ({', '.join(MITSUBA_STRATIFIED)}). "
            "wavefront: light sampling and roulette on (its defaults) on all cores, with its default sampler "
            "(sobol) and with sampler: independent; light sampling off means roulette off too (same sampler, "
            f"sobol). Medians of {runs} runs, each a fresh process with its own seed; wall times of the render "
            "(Mitsuba's JIT compilation excluded by a warm-up; wavefront's scene compile included, and its figure the "
            "second of two identical renders in its process, as Mitsuba's is its second: the first also pays "
            "one-time costs, such as first imports, and is shown in the last columns). MSE against each "
            f"renderer's own reference (wavefront {REFERENCE_SPP['wavefront']} spp, 2048 for cornell_spheres; "
            f"Mitsuba {REFERENCE_SPP['mitsuba']} spp; cached in benchmarks/references/); efficiency ratio = "
            "(time x MSE) of wavefront over "
            f"Mitsuba's.\n\n{text}"), data


def section_distributed(runs):
    try:
        import dask.distributed  # noqa: F401
    except ImportError:
        return "Dask is not installed (pip install -e '.[distributed]'); skipped.", {}
    args = {"scene": "scenes/final_scene.yaml", "runs": runs}
    rows, data = [], {}
    for label, dask, n in (("local, 1 process", False, 1), ("local, 2 processes", False, 2),
                           ("Dask local:1", True, 1), ("Dask local:2", True, 2)):
        data[label] = child(DASK_CHILD, dict(args, dask=dask, workers=n))
    base = data["local, 1 process"]["elapsed"]
    for label, r in data.items():
        rows.append([label, f"{r['elapsed']:.2f} s", f"{base / r['elapsed']:.2f}x", r["tasks"]])
    extra = data["Dask local:1"]["elapsed"] - base
    units = data["Dask local:1"]["units"]
    data["overhead_per_task_s"] = extra / data["Dask local:1"]["tasks"]
    data["overhead_per_unit_s"] = extra / units
    text = table(["final_scene 400x225, 10 spp", "wall time", "speed-up vs 1 process", "tasks"], rows)
    text += (f"\n\nDask overhead (local:1 minus 1 process): {extra * 1e3:.0f} ms in all, "
             f"{data['overhead_per_task_s'] * 1e3:.1f} ms per task, {data['overhead_per_unit_s'] * 1e3:.1f} ms "
             f"per unit ({units} units of a 64x64 tile x a pass of 1 to 16 samples per pixel)")
    return f"Medians of {runs} renders after one warm-up, in one process per row.\n\n{text}", data


def tree_rss(pid: int) -> int:
    """Resident bytes of ``pid`` and all its descendants, now (0 once gone)."""
    total, todo = 0, [pid]
    page = os.sysconf("SC_PAGE_SIZE")
    while todo:
        p = todo.pop()
        try:
            with open(f"/proc/{p}/statm") as f:
                total += int(f.read().split()[1]) * page
            for task in os.listdir(f"/proc/{p}/task"):
                with open(f"/proc/{p}/task/{task}/children") as f:
                    todo.extend(int(c) for c in f.read().split())
        except (OSError, ValueError):
            pass
    return total


def measure_command(argv: list[str]) -> dict:
    """Run ``argv``; its wall time, exit status, last stderr line and the peak
    of its whole process tree's resident memory, polled every 2 ms (sums of
    resident sets: pages shared by a forked worker count once per process)."""
    import time

    start = time.perf_counter()
    proc = subprocess.Popen(argv, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, cwd=ROOT)
    peak = 0
    while proc.poll() is None:
        peak = max(peak, tree_rss(proc.pid))
        time.sleep(0.002)
    err = proc.stderr.read().strip().splitlines()
    return {"wall": time.perf_counter() - start, "status": proc.returncode, "peak": peak,
            "line": err[-1] if err else ""}


def write_random_scene(count: int, path: Path) -> None:
    """``random_sphere_scene(count)`` as a YAML file, so loading it is measured too."""
    scene = random_sphere_scene(count)
    lines = ["camera: {look_from: [%r, %r, %r], look_at: [0, 0, 0], vfov: 45}" % scene.camera.look_from,
             "materials:", "  ground: {type: lambertian, albedo: [0.5, 0.5, 0.5]}",
             "  matte: {type: lambertian, albedo: [0.6, 0.3, 0.2]}",
             "  metal: {type: metal, albedo: [0.8, 0.8, 0.8], fuzz: 0.2}",
             "  glass: {type: dielectric, refraction_index: 1.5}", "spheres:"]
    lines += ["  - {center: [%r, %r, %r], radius: %r, material: %s}" % (*s.center, s.radius, s.material)
              for s in scene.spheres]
    path.write_text("\n".join(lines) + "\n")


def section_budget(runs):
    """``--memory`` against the measured peak of the whole process tree."""
    import tempfile

    tmp = Path(tempfile.mkdtemp(prefix="wavefront-bench-"))
    many = tmp / "random200k.yaml"
    write_random_scene(200_000, many)
    # the PNG floor: ~145 MiB while PNGs were encoded by importing colour-science, ~80 MiB since
    cases = [("three_spheres 400x225, 4 spp (PNG floor)", "scenes/three_spheres.yaml", ["--spp", "4"],
              ("80M",)),
             ("W2 final_scene 400x225, 10 spp", "scenes/final_scene.yaml", [], ("256M", "1G")),
             ("three_spheres 3840x2160, 1 spp", "scenes/three_spheres.yaml",
              ["--width", "3840", "--height", "2160", "--spp", "1"], ("256M", "1G")),
             ("three_spheres 7680x4320, 1 spp", "scenes/three_spheres.yaml",
              ["--width", "7680", "--height", "4320", "--spp", "1"], ("1G", "2G")),
             ("200,000 spheres 400x225, 1 spp", str(many), ["--spp", "1"], ("256M", "1G"))]
    wavefront = str(Path(PYTHON).parent / "wavefront")
    rows, data = [], {}
    for label, scene, flags, budgets in cases:
        for budget in budgets:
            r = measure_command([wavefront, "render", scene, "-o", str(tmp / "out.png"), "--workers", "2",
                                 "--memory", budget, *flags])
            data[f"{label} @ {budget}"] = r
            if r["status"] == 0:
                reported = r["line"].split("peak memory ")[1].split(",")[0]
                workers = r["line"].rsplit(", ", 1)[1]
                outcome = f"rendered, {workers}"
            else:
                reported = "-"
                outcome = "refused: " + r["line"].split("error: ")[-1][:70]
            limit = int(budget[:-1]) << {"M": 20, "G": 30}[budget[-1]]
            within = "yes" if r["peak"] <= limit else "**no**"
            rows.append([label, budget, outcome, reported, fmt_mib(r["peak"]), within, f"{r['wall']:.1f} s"])
    text = table(["render (PNG out, --workers 2)", "--memory", "outcome", "reported peak", "measured tree peak",
                  "within budget", "wall time"], rows)
    return ("Each row is one `wavefront render` process, its whole process tree's resident memory polled "
            "every 2 ms (a sum of resident sets, so pages a forked worker shares with the parent count "
            f"twice, as the budget counts them); loading, rendering and writing the PNG included.\n\n{text}"), data


# --- start-up and whole process -----------------------------------------------

# The real command (``wavefront.cli.main``) with timers around the functions
# that make up its fixed costs; every timestamp is ``time.perf_counter()``,
# CLOCK_MONOTONIC on Linux, the same clock in the benchmark's process, so the
# interpreter's start (launch to this script's first line) and its exit (the
# command's return to the process's end) are measured from outside.
STARTUP_CHILD = textwrap.dedent("""
    import time
    first = time.perf_counter()
    import json, os, sys
    args = json.loads(sys.argv[1])
    import wavefront.cli as cli
    imported = time.perf_counter()
    import importlib, multiprocessing.context
    # by module (the package's ``wavefront.render`` is the function of that name)
    accel, output, render, scenefile = (importlib.import_module(f"wavefront.{name}")
                                        for name in ("accel", "output", "render", "scenefile"))
    spans = {}

    def timed(owner, name, label):
        inner = getattr(owner, name)

        def wrapper(*a, **k):
            start = time.perf_counter()
            try:
                return inner(*a, **k)
            finally:
                spans.setdefault(label, []).append((start, time.perf_counter()))

        setattr(owner, name, wrapper)

    timed(cli, "main", "main")
    timed(cli, "check_paths", "paths")
    timed(scenefile, "load_scene", "load")
    timed(scenefile, "read_yaml", "yaml")
    timed(scenefile, "_scene_from_document", "validate")
    timed(render, "compile_within", "compile")
    timed(accel, "build_intersector", "bvh")
    timed(render, "render_scene", "render")
    if hasattr(render, "_Workers"):  # its own worker processes (trees before it: multiprocessing.Pool)
        timed(render, "_Workers", "pool")
    else:
        timed(multiprocessing.context.BaseContext, "Pool", "pool")
    timed(output, "encode_srgb8", "encode")
    timed(output, "write_image", "write")
    init_worker = render._init_worker

    def ready(*a, **k):  # a forked worker says when it is ready for its first task
        init_worker(*a, **k)
        with open(os.path.join(args["ready"], str(os.getpid())), "w") as f:
            f.write(repr(time.perf_counter()))

    render._init_worker = ready
    sys.argv = ["wavefront", *args["argv"]]
    # what the console script runs (trees from before it existed: main)
    status = cli.command() if hasattr(cli, "command") else cli.main()
    print(json.dumps({"first": first, "imported": imported, "spans": spans, "status": status}), flush=True)
    sys.exit(status)
""")

# The parts of the command, in order: (label, how to get its seconds from one run).
STARTUP_PARTS = (
    "interpreter start (python, site, the entry point)",
    "imports (wavefront, NumPy, PyYAML, multiprocessing...)",
    "arguments and output checks",
    "scene: YAML to values (libyaml)",
    "scene: validation to objects",
    "scene: rest of loading (file read, flags)",
    "compile (arrays, materials, emitters)",
    "BVH build",
    "pool start (fork, until every worker is ready)",
    "render (planning, tracing, merging)",
    "encode (8-bit sRGB)",
    "PNG write (Pillow, compression, file, rename)",
    "rest of the command (signals, summary)",
    "interpreter exit",
)

# Workloads of the start-up breakdown: the 0.5 s floor, then W2 as a user runs it.
STARTUP_WORKLOADS = (
    ("final_scene 40x23, 1 spp (the floor: <= 0.5 s)", "scenes/final_scene.yaml",
     ["--spp", "1", "--width", "40", "--height", "23"]),
    ("W2 final_scene 400x225, 10 spp", "scenes/final_scene.yaml", []),
)


def user_env(tree: str | None = None) -> tuple[dict, Path]:
    """Environment and working directory of a command as a user runs it.

    Bytecode is cached (``__pycache__``, as after ``pip install``), whatever
    PYTHONDONTWRITEBYTECODE says here: without it every process compiles
    wavefront's modules again (~50 ms).  ``tree``: run the wavefront source
    tree in that folder instead (first on ``sys.path``).
    """
    env = {k: v for k, v in os.environ.items() if k != "PYTHONDONTWRITEBYTECODE"}
    if tree is None:
        return env, ROOT
    env["PYTHONPATH"] = tree
    return env, Path(tree)  # python -c puts the working directory first on sys.path


def _span(spans, label):
    return sum(b - a for a, b in spans.get(label, ()))


def startup_run(scene: str, flags: list[str], out: str, tree: str | None = None) -> dict:
    """One ``wavefront render`` under STARTUP_CHILD; seconds of each of STARTUP_PARTS.

    ``tree``: a source tree of wavefront to run instead of this one (its
    ``wavefront/`` first on ``sys.path``), for before/after comparisons.
    """
    import tempfile
    import time

    ready = tempfile.mkdtemp(prefix="wavefront-ready-")
    env, cwd = user_env(tree)
    argv = ["render", str(ROOT / scene), "-o", out, *flags]
    launch = time.perf_counter()
    proc = subprocess.run([PYTHON, "-c", STARTUP_CHILD, json.dumps({"argv": argv, "ready": ready})],
                          capture_output=True, text=True, cwd=cwd, env=env, timeout=3600)
    exited = time.perf_counter()
    if proc.returncode != 0:
        raise RuntimeError(proc.stderr.strip().splitlines()[-1] if proc.stderr.strip() else "child failed")
    r = json.loads(proc.stdout.strip().splitlines()[-1])
    spans = r["spans"]
    workers_ready = []
    for name in os.listdir(ready):
        with open(os.path.join(ready, name)) as f:
            workers_ready.append(float(f.read()))
        os.unlink(os.path.join(ready, name))
    os.rmdir(ready)
    pool = (max(workers_ready) - spans["pool"][0][0]) if workers_ready and "pool" in spans else 0.0
    (main_start, main_end), = spans["main"]
    parts = [r["first"] - launch, r["imported"] - r["first"], _span(spans, "paths"), _span(spans, "yaml"),
             _span(spans, "validate"), None, _span(spans, "compile") - _span(spans, "bvh"), _span(spans, "bvh"),
             pool, _span(spans, "render") - pool, _span(spans, "encode"),
             _span(spans, "write") - _span(spans, "encode"), None, exited - main_end]
    load = _span(spans, "load") - _span(spans, "yaml") - _span(spans, "validate")
    parts[5] = load
    inside = sum(p for p in parts[2:12])
    parts[12] = (main_end - main_start) - inside
    parts[1] += main_start - r["imported"]  # the timers' own set-up: negligible, but not lost
    return {"parts": parts, "total": exited - launch}


IMPORT_GROUPS = ("numpy", "wavefront", "yaml", "PIL", "imageio", "multiprocessing", "colour", "scipy")


def import_breakdown(scene: str, flags: list[str], out: str, tree: str | None = None) -> dict:
    """Self time of every module the command imports, by top-level package,
    from ``python -X importtime`` (which slows imports down: read shares)."""
    env, cwd = user_env(tree)
    code = "import sys, wavefront.cli; sys.exit(wavefront.cli.main(sys.argv[1:]))"
    proc = subprocess.run([PYTHON, "-X", "importtime", "-c", code, "render", str(ROOT / scene), "-o", out, *flags],
                          capture_output=True, text=True, cwd=cwd, env=env, timeout=3600)
    groups: dict[str, float] = {}
    for line in proc.stderr.splitlines():
        if not line.startswith("import time:") or "self [us]" in line:
            continue
        self_us, _, name = (x.strip() for x in line[len("import time:"):].split("|"))
        top = name.split(".")[0]
        group = top if top in IMPORT_GROUPS else ("other packages" if _third_party(top) else "standard library")
        groups[group] = groups.get(group, 0.0) + int(self_us) / 1e6
    return groups


def _third_party(top: str) -> bool:
    import importlib.util

    try:
        spec = importlib.util.find_spec(top)
    except (ImportError, ValueError):
        return False
    return bool(spec and spec.origin and "site-packages" in spec.origin)


def section_startup(runs, tree: str | None = None):
    """Every fixed cost of ``wavefront render``, each part's share; with
    ``tree``, the same for another source tree, interleaved run by run."""
    import tempfile

    out = str(Path(tempfile.mkdtemp(prefix="wavefront-startup-")) / "out.png")
    trees = [("this tree", None)] + ([(f"{tree}", tree)] if tree else [])
    data, text = {}, []
    for label, scene, flags in STARTUP_WORKLOADS:
        startup_run(scene, flags, out)  # warm the page cache and __pycache__
        for _, t in trees[1:]:
            startup_run(scene, flags, out, t)
        results = {name: [] for name, _ in trees}
        for _ in range(runs):  # interleaved, so both trees see the same machine load
            for name, t in trees:
                results[name].append(startup_run(scene, flags, out, t))
        medians = {name: {"parts": [statistics.median(r["parts"][i] for r in rs) for i in range(len(STARTUP_PARTS))],
                          "total": statistics.median(r["total"] for r in rs)} for name, rs in results.items()}
        data[label] = medians
        header = ["part"]
        for name, _ in trees:
            header += [f"{name}: seconds", "share"]
        rows = []
        for i, part in enumerate(STARTUP_PARTS):
            row = [part]
            for name, _ in trees:
                m = medians[name]
                row += [f"{m['parts'][i]:.3f}", f"{m['parts'][i] / m['total'] * 100:.0f} %"]
            rows.append(row)
        total = ["**total, launch to exit**"]
        for name, _ in trees:
            total += [f"**{medians[name]['total']:.3f}**", "100 %"]
        rows.append(total)
        text.append(f"`wavefront render {scene} {' '.join(flags)} -o out.png`, {label}; medians of {runs} runs "
                    f"(each part's median; the total is the median of the totals):\n\n" + table(header, rows))
    # imports by package, for the first workload
    label, scene, flags = STARTUP_WORKLOADS[0]
    groups = {name: [] for name, _ in trees}
    for _ in range(runs):
        for name, t in trees:
            groups[name].append(import_breakdown(scene, flags, out, t))
    names = sorted({g for gs in groups.values() for r in gs for g in r},
                   key=lambda g: -statistics.median(r.get(g, 0.0) for r in groups["this tree"]))
    header, rows = ["package (self time of its modules)"], []
    for name, _ in trees:
        header += [f"{name}: ms", "share"]
    for g in names:
        row = [g]
        for name, _ in trees:
            value = statistics.median(r.get(g, 0.0) for r in groups[name])
            whole = statistics.median(sum(r.values()) for r in groups[name])
            row += [f"{value * 1e3:.0f}", f"{value / whole * 100:.0f} %"]
        rows.append(row)
    data["imports"] = {name: gs for name, gs in groups.items()}
    text.append(f"Imports of `wavefront render {scene} {' '.join(flags)}` by package, from `python -X importtime` "
                f"(which slows every import: read the shares; medians of {runs} runs):\n\n" + table(header, rows))
    intro = ("Each part of one `wavefront render` process: the command itself (`wavefront.cli.main`) with timers "
             "around its functions, the interpreter's start and exit measured from outside on the same clock. "
             "The pool start overlaps nothing: the render starts its tasks when the workers are ready; it is "
             "counted apart from the render.")
    return intro + "\n\n" + "\n\n".join(text), data


# Mitsuba from ``python`` launch to an EXR on disk: import, the scene (a JSON
# dict written by benchmarks/mitsuba_scene.py beforehand, so that neither
# wavefront nor its YAML is part of Mitsuba's time), Dr.Jit's cached kernels,
# the render, the write.  It prints when the EXR was on disk, then renders once
# more (steady state, its in-process figure), which the whole-process time
# does not include.
MITSUBA_WHOLE_CHILD = textwrap.dedent("""
    import time
    first = time.perf_counter()
    import json, sys
    args = json.loads(sys.argv[1])
    import mitsuba as mi
    mi.set_variant(args["variant"])
    sys.path.insert(0, args["bench_dir"])
    from mitsuba_scene import load_scene_dict
    imported = time.perf_counter()
    scene = mi.load_dict(load_scene_dict(args["scene"], mi))
    loaded = time.perf_counter()
    image = mi.render(scene)
    mi.Bitmap(image).write(args["out"])
    written = time.perf_counter()
    start = time.perf_counter()
    import numpy as np
    np.array(mi.render(scene))  # the same kernels again: no compilation
    steady = time.perf_counter() - start
    print(json.dumps({"first": first, "imported": imported, "loaded": loaded, "written": written,
                      "steady": steady}), flush=True)
""")

WHOLE_WORKLOADS = (("W1 three_spheres 400x225, 100 spp", "scenes/three_spheres.yaml", {}),
                   ("W2 final_scene 400x225, 10 spp", "scenes/final_scene.yaml", {}))
W3 = ("W3 final_scene 1200x675, 500 spp", "scenes/final_scene.yaml",
      {"width": 1200, "height": 675, "samples_per_pixel": 500})


MITSUBA_SPEC_CHILD = textwrap.dedent("""
    import json, sys
    args = json.loads(sys.argv[1])
    import mitsuba as mi
    mi.set_variant(args["variant"])
    sys.path.insert(0, args["bench_dir"])
    from mitsuba_scene import mitsuba_scene_dict, save_scene_dict
    import wavefront
    scene = wavefront.load_scene(args["scene"]).with_overrides(**args["overrides"])
    save_scene_dict(mitsuba_scene_dict(scene, mi, workdir=args["folder"]), mi, args["out"])
    print("{}")
""")


def _mitsuba_spec(label: str, scene: str, overrides: dict, folder: Path, variant: str, env: dict) -> str:
    """Write Mitsuba's dict of ``scene`` as JSON once (untimed); its path, for MITSUBA_WHOLE_CHILD."""
    path = folder / (label.split()[0] + ".json")
    child(MITSUBA_SPEC_CHILD, {"scene": scene, "overrides": overrides, "variant": variant, "out": str(path),
                               "folder": str(folder), "bench_dir": str(ROOT / "benchmarks")}, env)
    return str(path)


def _flags(overrides: dict) -> list[str]:
    names = {"width": "--width", "height": "--height", "samples_per_pixel": "--spp"}
    return [x for k, v in overrides.items() for x in (names[k], str(v))]


def _wavefront_command(scene: str, overrides: dict, out: str, extra=()) -> dict:
    """``wavefront render`` as a user runs it (stderr is a pipe: no progress bar); wall time and the
    render time of its summary.  ``extra``: more flags."""
    import time

    env, cwd = user_env()
    argv = [str(Path(PYTHON).parent / "wavefront"), "render", str(ROOT / scene), "-o", out, *_flags(overrides),
            *extra]
    start = time.perf_counter()
    proc = subprocess.run(argv, capture_output=True, text=True, cwd=cwd, env=env, timeout=7200)
    wall = time.perf_counter() - start
    if proc.returncode != 0:
        raise RuntimeError(proc.stderr.strip().splitlines()[-1] if proc.stderr.strip() else "wavefront failed")
    line = proc.stderr.strip().splitlines()[-1]
    render = float(line.split("render ")[1].split(" s")[0])
    return {"wall": wall, "render": render}


def _mitsuba_command(spec: str, variant: str, env: dict, out: str) -> dict:
    import time

    launch = time.perf_counter()
    r = child(MITSUBA_WHOLE_CHILD, {"scene": spec, "variant": variant, "out": out,
                                    "bench_dir": str(ROOT / "benchmarks")}, env)
    return {"wall": r["written"] - launch, "render": r["written"] - r["loaded"], "steady": r["steady"],
            "start": r["loaded"] - launch}


def section_whole_process(runs, w3=None):
    """W1 and W2 as a user runs them: launch to image on disk, wavefront's CLI
    against Mitsuba's whole process, medians of interleaved runs; beside
    them the in-process figures (wavefront's ``render_scene`` in a fresh
    process, as the workloads section; Mitsuba's steady-state render)."""
    import tempfile

    variant, env, note = mitsuba_setup()
    if env is not None:  # both renderers with their bytecode cached, as a user runs them
        env = {k: v for k, v in env.items() if k != "PYTHONDONTWRITEBYTECODE"}
    folder = Path(tempfile.mkdtemp(prefix="wavefront-whole-"))
    png, exr = str(folder / "out.png"), str(folder / "out.exr")
    workloads = list(WHOLE_WORKLOADS) + ([w3] if w3 else [])
    rows, data = [], {}
    load_before = os.getloadavg()[0]
    for label, scene, overrides in workloads:
        once = w3 is not None and (label, scene, overrides) == w3
        n = 1 if once else runs
        spec = _mitsuba_spec(label, scene, overrides, folder, variant, env) if variant else None
        if not once:  # warm-ups: the page cache, __pycache__, Dr.Jit's kernel cache
            _wavefront_command(scene, overrides, png)
            if variant:
                _mitsuba_command(spec, variant, env, exr)
        # the default sampler (sobol) spends time per sample on less noise; the independent one is
        # the estimator Mitsuba's default sampler matches, sample for sample (W1 and W2 only)
        results = {"wavefront": [], "independent": [], "in process": [], "mitsuba": []}
        for _ in range(n):
            results["wavefront"].append(_wavefront_command(scene, overrides, png))
            if not once:
                results["independent"].append(_wavefront_command(scene, overrides, png, ("--sampler", "independent")))
            if variant:
                results["mitsuba"].append(_mitsuba_command(spec, variant, env, exr))
            results["in process"].append(child(WAVEFRONT_CHILD, {"scene": scene, "overrides": overrides},
                                               user_env()[0]))
        med = lambda rs, key: statistics.median(r[key] for r in rs)  # noqa: E731
        w_wall, w_render = med(results["wavefront"], "wall"), med(results["wavefront"], "render")
        w_in = med(results["in process"], "elapsed")
        entry = {"wavefront_wall": w_wall, "wavefront_render": w_render, "wavefront_in_process": w_in,
                 "runs": n}
        if variant:
            m_wall, m_steady = med(results["mitsuba"], "wall"), med(results["mitsuba"], "steady")
            m_start = med(results["mitsuba"], "start")
            # ratios run by run (each wavefront run against the Mitsuba run next to it), then
            # their median: steadier than a ratio of medians when the machine's load drifts
            whole = statistics.median(w["wall"] / m["wall"] for w, m in zip(results["wavefront"], results["mitsuba"]))
            inner = statistics.median(w["elapsed"] / m["steady"]
                                      for w, m in zip(results["in process"], results["mitsuba"]))
            plain = (statistics.median(w["wall"] / m["wall"] for w, m in zip(results["independent"],
                                                                              results["mitsuba"]))
                     if results["independent"] else None)
            entry.update(mitsuba_wall=m_wall, mitsuba_steady=m_steady, mitsuba_start=m_start,
                         ratio_whole_independent=plain, runs_independent=results["independent"],
                         mitsuba_first_render=med(results["mitsuba"], "render"), ratio_whole=whole,
                         ratio_in_process=inner, runs_wavefront=results["wavefront"],
                         runs_mitsuba=results["mitsuba"], runs_in_process=results["in process"])
            independent = (f"{med(results['independent'], 'wall'):.2f} s ({plain:.2f}x)" if plain is not None
                           else "–")
            rows.append([label, f"{w_wall:.2f} s", f"{m_wall:.2f} s", f"**{whole:.2f}x**", independent,
                         f"{w_in:.2f} s", f"{m_steady:.2f} s", f"{inner:.2f}x", n])
        else:
            rows.append([label, f"{w_wall:.2f} s", "–", "–", "–", f"{w_in:.2f} s", "–", "–", n])
        data[label] = entry
    text = table(["workload", "wavefront CLI, launch to PNG", "Mitsuba, launch to EXR", "ratio",
                  "CLI with --sampler independent (ratio)", "wavefront in process", "Mitsuba steady-state render", "ratio", "runs"], rows)
    text += (f"\n\nTimes are medians; each ratio is the median of the runs' own ratios (a wavefront run "
             f"against the Mitsuba run beside it). Load average (1 min) {load_before:.1f} before, "
             f"{os.getloadavg()[0]:.1f} after, on {os.cpu_count()} cores.")
    return (f"Whole process: `wavefront render SCENE -o out.png` (both cores, flags for the size) from launch to "
            f"exit, against {note} from `python` launch to the EXR on disk (import, loading the scene from a "
            "JSON dict written beforehand by benchmarks/mitsuba_scene.py, Dr.Jit's cached kernels, render, "
            "write). In process, as the workloads section: wavefront's `render_scene` in a fresh process "
            "(compile and BVH included), Mitsuba's second render in the same process. After one warm-up "
            f"of each, medians of {runs} interleaved runs (W3: one run each, no warm-up: Dr.Jit may compile "
            f"its kernels for a new image size once).\n\n{text}"), data


def plot_scaling(data, path):
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        return False
    counts = [n for n in data if isinstance(n, int)]
    fig, ax = plt.subplots(figsize=(6, 4))
    ax.loglog(counts, [data[n]["auto_ns_per_segment"] for n in counts], "o-", label="wavefront (automatic)")
    brute = [n for n in counts if "brute_ns_per_segment" in data[n]]
    ax.loglog(brute, [data[n]["brute_ns_per_segment"] for n in brute], "s--", label="brute force")
    ax.set_xlabel("spheres")
    ax.set_ylabel("time per path segment (ns, one core)")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    return True


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=3)
    parser.add_argument("--section", choices=("all", "workloads", "whole_process", "startup", "geometry", "next_week",
                                              "equal_error", "scaling", "memory", "budget", "capacity", "distributed"),
                        default="all")
    parser.add_argument("--compare-tree", metavar="DIR",
                        help="startup: also measure the wavefront source tree in DIR (e.g. an older commit's "
                             "`git archive`), interleaved run by run")
    parser.add_argument("--no-w3", dest="w3", action="store_false",
                        help="whole_process: leave out W3, the cover at 1200x675 and 500 spp, one run each "
                             "(several minutes)")
    parser.add_argument("--w3-size", metavar="WxHxSPP", default="1200x675x500",
                        help="W3's width, height and samples per pixel (a smaller one checks the set-up)")
    args = parser.parse_args(argv)
    RESULTS.mkdir(parents=True, exist_ok=True)
    sections = (("workloads", "whole_process", "startup", "geometry", "next_week", "equal_error", "scaling", "memory",
                 "budget", "capacity", "distributed")
                if args.section == "all"
                else (args.section,))
    w3 = None
    if args.w3:
        width, height, spp = (int(x) for x in args.w3_size.split("x"))
        w3 = (f"W3 final_scene {width}x{height}, {spp} spp", W3[1],
              {"width": width, "height": height, "samples_per_pixel": spp})
    options = {"startup": {"tree": args.compare_tree}, "whole_process": {"w3": w3}}
    everything = {}
    for name in sections:
        print(f"\n## {name}\n", flush=True)
        text, data = globals()[f"section_{name}"](args.runs, **options.get(name, {}))
        print(text, flush=True)
        (RESULTS / f"{name}.md").write_text(text + "\n")
        everything[name] = data
        if name == "scaling" and plot_scaling(data, RESULTS / "scaling.png"):
            print(f"\nplot: {RESULTS / 'scaling.png'}")
    (RESULTS / f"results-{args.section}.json").write_text(json.dumps(everything, indent=1, default=str) + "\n")


if __name__ == "__main__":
    main()
