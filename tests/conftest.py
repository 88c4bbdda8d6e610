"""Session-wide test configuration: float64 support and deterministic hypothesis settings."""

import jax
from hypothesis import HealthCheck, settings

# Enable float64 once, before any test builds an array; float32 is tested explicitly by
# building shapes and poses with float32 inputs.
jax.config.update("jax_enable_x64", True)
# Strict promotion: mixing float32 and float64 arrays (or ints and floats) raises instead of
# silently widening, so a query whose output dtype does not follow its inputs fails here.
jax.config.update("jax_numpy_dtype_promotion", "strict")

settings.register_profile(
    "jaxsat",
    deadline=None,
    derandomize=True,
    max_examples=25,
    print_blob=True,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture],
)
settings.load_profile("jaxsat")
