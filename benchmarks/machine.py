"""What a benchmark ran on: one record for the JSON and the header of every script here.

`machine_info()` gives the date, platform, Python, CPU model and count, load average at the
start, available memory, versions of the named distributions, the git commit of this checkout
(with "+dirty" when its working tree has changes) and JAX's backend and devices.
"""

from __future__ import annotations

import datetime
import importlib.metadata
import os
import pathlib
import platform
import subprocess

HERE = pathlib.Path(__file__).resolve().parent
DISTRIBUTIONS = ("jax", "jaxlib", "jaxsat", "numpy", "scipy")


def cpu_model() -> str:
    try:
        with open("/proc/cpuinfo") as cpuinfo:
            for line in cpuinfo:
                if line.startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown"


def load_average() -> list[float] | None:
    """1, 5 and 15 minute load averages, rounded to 0.01 (None where the OS has none)."""
    return [round(x, 2) for x in os.getloadavg()] if hasattr(os, "getloadavg") else None


def available_memory_bytes() -> int | None:
    try:
        with open("/proc/meminfo") as meminfo:
            for line in meminfo:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    return None


def versions(distributions=DISTRIBUTIONS) -> dict[str, str | None]:
    found = {}
    for name in distributions:
        try:
            found[name] = importlib.metadata.version(name)
        except importlib.metadata.PackageNotFoundError:
            found[name] = None
    return found


def git_commit() -> str | None:
    """Short commit of this checkout, "+dirty" when its working tree has changes."""
    def git(*args):
        return subprocess.run(["git", "-C", str(HERE), *args], capture_output=True, text=True,
                              timeout=10, check=True).stdout.strip()
    try:
        commit = git("rev-parse", "--short", "HEAD")
        return commit + ("+dirty" if git("status", "--porcelain") else "")
    except (OSError, subprocess.SubprocessError):
        return None


def machine_info(distributions=DISTRIBUTIONS) -> dict:
    import jax

    return {
        "date_utc": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
        "platform": platform.platform(),
        "python": platform.python_version(),
        "cpu_model": cpu_model(),
        "cpu_count": os.cpu_count(),
        "load_average_start": load_average(),
        "memory_available_bytes": available_memory_bytes(),
        "versions": versions(distributions),
        "git_commit": git_commit(),
        "backend": jax.default_backend(),
        "devices": [str(device) for device in jax.devices()],
    }
