"""Generate scenes/bouncing_spheres.yaml: the motion-blur cover of "Ray Tracing: The Next Week".

Book 1's final scene with two changes from book 2: every diffuse ball
bounces (``center1 = center + (0, uniform(0, 0.5), 0)``, section 2.5) and
the ground is the solid checker (section 4.3).  Drawn once from a fixed seed
so the committed file is reproducible:

    python scenes/make_bouncing_spheres.py > scenes/bouncing_spheres.yaml
"""

import numpy as np

from make_final_scene import cover, write  # the same book-1 scene, drawn the same way

SEED = 20240602


def main():
    ground = "{type: lambertian, albedo: {type: checker, scale: 0.32, even: [0.2, 0.3, 0.1], odd: [0.9, 0.9, 0.9]}}"
    materials, spheres = cover(np.random.default_rng(SEED), ground, bounce=True)
    write(__doc__, "make_bouncing_spheres.py", SEED, materials, spheres, spp=100)


if __name__ == "__main__":
    main()
