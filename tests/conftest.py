import os

from hypothesis import HealthCheck, settings

# CI and local runs share one profile: enough examples to find real bugs,
# bounded so `make test` stays within a few minutes on 2 cores.
settings.register_profile("wavefront", max_examples=200, deadline=None,
                          suppress_health_check=[HealthCheck.too_slow])
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "wavefront"))
