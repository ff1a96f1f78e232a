"""Writes book_estimator.npz: images of the path integrator as it was before light sampling and
roulette (commit a809293), which tests/test_lights.py requires the both-off estimator to reproduce
bit for bit.  Run from the repository root with that commit checked out."""
import numpy as np
from pathlib import Path
from wavefront import load_scene, render
S = Path("scenes")
out = {}
cb = load_scene(S/"cornell_box.yaml").with_overrides(width=16, height=16, samples_per_pixel=4, max_depth=12)
out["cornell_box"] = render(cb, workers=1)
ts = load_scene(S/"three_spheres.yaml").with_overrides(width=16, height=9, samples_per_pixel=4)
out["three_spheres"] = render(ts, workers=1)
for k,v in out.items(): print(k, v.dtype, v.shape, v.mean())
np.savez_compressed("tests/data/book_estimator.npz", **out)
