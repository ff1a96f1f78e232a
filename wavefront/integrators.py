"""The integrators by name: a scene's ``render.integrator`` picks its trace function here.

Each trace function takes ``(compiled_scene, job, key, capacity, stats,
should_stop)`` and returns the job's per-sample radiance ``(3, job.size)``;
it draws its numbers from ``path.render_sampler(compiled_scene, key)``.
A new integrator is one module and one entry below.  Those in ``STREAMING``
also take ``stream=`` (a :class:`~wavefront.path.TaskStream`): they run one
task into the next in one wavefront and hand each back when it is done.
"""

from __future__ import annotations

from .path import trace_paths
from .whitted import trace_whitted

TRACERS = {
    "path": trace_paths,  # backward path tracing (RTOW books 1-3)
    "whitted": trace_whitted,  # Whitted ray tracing with Phong shading and shadow rays
}

# integrators that take ``stream=``; Whitted's generations are cheap to drain
STREAMING = frozenset({"path"})
