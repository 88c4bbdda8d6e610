"""Session-wide test configuration: float64 support, strict dtype promotion, one compilation
cache per test run, compiled programs released after each test file, and deterministic
hypothesis settings."""

import atexit
import os
import pathlib
import shutil
import tempfile
import uuid

import jax
import pytest
from hypothesis import HealthCheck, settings

# Enable float64 once, before any test builds an array; float32 is tested explicitly by
# building shapes and poses with float32 inputs.
jax.config.update("jax_enable_x64", True)
# Strict promotion: mixing float32 and float64 arrays (or ints and floats) raises instead of
# silently widening, so a query whose output dtype does not follow its inputs fails here.
jax.config.update("jax_numpy_dtype_promotion", "strict")

# One compilation cache per test run, shared by both xdist workers and the processes they start
# (notebook kernels, scripts), so that a program compiles once per run however many test files
# build it (compiling is most of the suite's time). It starts empty and is removed at exit:
# nothing carries over from one run to the next.
_RUN = os.environ.get("PYTEST_XDIST_TESTRUNUID") or uuid.uuid4().hex
_CACHE = pathlib.Path(tempfile.gettempdir()) / f"jaxsat-test-compilations-{_RUN}"
os.environ["JAX_COMPILATION_CACHE_DIR"] = str(_CACHE)
os.environ["JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS"] = "0.5"
jax.config.update("jax_compilation_cache_dir", str(_CACHE))
jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.5)
atexit.register(shutil.rmtree, _CACHE, ignore_errors=True)

settings.register_profile(
    "jaxsat",
    deadline=None,
    derandomize=True,
    max_examples=25,
    print_blob=True,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture],
)
settings.load_profile("jaxsat")


@pytest.fixture(autouse=True, scope="module")
def _release_compiled_programs():
    """Drop every compiled program after each test file.

    A worker runs whole files (``--dist loadfile``) and would otherwise keep each program it ever
    compiled: 6-7.5 GiB per worker by the end of the suite, 15 GiB of the 24 on a 2-core machine.
    A later file that needs one again reads it back from the run's compilation cache above, or
    compiles it again where it took under half a second.
    """
    yield
    jax.clear_caches()
