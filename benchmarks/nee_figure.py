"""The README's light sampling figure: the Cornell box with light sampling off
and on, rendered for the same wall time, and their MSE against the cached
converged wavefront image of the equal-error benchmark.

    .venv/bin/python benchmarks/nee_figure.py        # writes docs/images/cornell_nee_{off,on}.png

Times are those of ``render_scene`` on all cores; the machine is shared and
noisy, so the equal-time match is within a few tens of percent (both times printed).
"""

from __future__ import annotations

import dataclasses
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from wavefront import load_scene, render_scene  # noqa: E402
from wavefront.output import write_image  # noqa: E402

SIZE = 128
ON_SPP = 16
REFERENCE = ROOT / "benchmarks" / "references" / f"cornell_box_{SIZE}_wavefront_sobol_4096spp.npy"


def main() -> None:
    # independent numbers on both sides, as when the README's figure was made (before the sobol sampler)
    scene = load_scene(ROOT / "scenes" / "cornell_box.yaml").with_overrides(width=SIZE, height=SIZE, seed=5,
                                                                            sampler="independent")
    off = scene.replace(render=dataclasses.replace(scene.render, light_sampling=False, russian_roulette=False))
    reference = np.load(REFERENCE).astype(np.float64) if REFERENCE.exists() else None
    on = render_scene(scene.with_overrides(samples_per_pixel=ON_SPP))
    probe = render_scene(off.with_overrides(samples_per_pixel=ON_SPP))  # the book estimator's cost per sample
    off_spp = max(1, round(ON_SPP * on.stats.elapsed / probe.stats.elapsed))
    book = render_scene(off.with_overrides(samples_per_pixel=off_spp))
    for name, result, spp in (("off", book, off_spp), ("on", on, ON_SPP)):
        mse = float(((result.image - reference) ** 2).mean()) if reference is not None else float("nan")
        write_image(str(ROOT / "docs" / "images" / f"cornell_nee_{name}.png"), result.image)
        print(f"light sampling {name}: {spp} spp, {result.stats.elapsed:.2f} s, MSE {mse:.4g}, "
              f"time x MSE {result.stats.elapsed * mse:.4g}")


if __name__ == "__main__":
    main()
