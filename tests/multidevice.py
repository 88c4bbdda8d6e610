"""Run a Python snippet in a fresh interpreter that sees several CPU devices.

The device count must be set (XLA_FLAGS) before jax is imported, and tests/conftest.py imports
jax first, so multi-device tests run their checks in a subprocess. Each call pays one JAX start
(a few seconds): combine checks into one snippet.

    from multidevice import run_on_devices

    output = run_on_devices('''
        import jax
        print(len(jax.devices()))
    ''')
"""

from __future__ import annotations

import os
import pathlib
import subprocess
import sys
import textwrap

_TESTS = pathlib.Path(__file__).resolve().parent
_DEVICE_COUNT_FLAG = "--xla_force_host_platform_device_count"


def run_on_devices(code: str, num_devices: int = 4, *, enable_x64: bool = True,
                   timeout: float = 600) -> str:
    """Run `code` with `num_devices` CPU devices and return its stdout.

    The snippet runs with the repository root and tests/ on the path (so `import jaxsat` and
    `import oracle` work), JAX_PLATFORMS=cpu and JAX_ENABLE_X64 set by `enable_x64`. It is
    dedented, and preceded by a check that jax really sees `num_devices` devices.

    Raises:
      AssertionError: the snippet exited with an error (the message holds its stdout and
        stderr) or ran longer than `timeout` seconds.
    """
    prologue = (f"import jax\nassert len(jax.devices()) == {num_devices}, "
                f"f'expected {num_devices} devices, got {{jax.devices()}}'\n")
    try:
        result = subprocess.run([sys.executable, "-c", prologue + textwrap.dedent(code)],
                                env=_environment(num_devices, enable_x64), capture_output=True,
                                text=True, timeout=timeout, cwd=_TESTS.parent)
    except subprocess.TimeoutExpired as error:
        output = [stream.decode() if isinstance(stream, bytes) else stream or ""
                  for stream in (error.stdout, error.stderr)]  # bytes despite text=True
        raise AssertionError(f"snippet ran longer than {timeout} s.\nstdout:\n{output[0]}\n"
                             f"stderr:\n{output[1]}") from None
    if result.returncode != 0:
        raise AssertionError(f"snippet failed (exit code {result.returncode}).\nstdout:\n"
                             f"{result.stdout}\nstderr:\n{result.stderr}")
    return result.stdout


def _environment(num_devices: int, enable_x64: bool) -> dict[str, str]:
    """This process's environment with the device count, platform, x64 and paths set."""
    env = dict(os.environ)
    # Drop any device count already there: the last flag would win, but say it once.
    flags = [flag for flag in env.get("XLA_FLAGS", "").split()
             if not flag.startswith(_DEVICE_COUNT_FLAG)]
    env["XLA_FLAGS"] = " ".join([*flags, f"{_DEVICE_COUNT_FLAG}={num_devices}"])
    env["JAX_PLATFORMS"] = "cpu"
    env["JAX_ENABLE_X64"] = "1" if enable_x64 else "0"
    paths = [str(_TESTS.parent), str(_TESTS), env.get("PYTHONPATH", "")]
    env["PYTHONPATH"] = os.pathsep.join(path for path in paths if path)
    return env
