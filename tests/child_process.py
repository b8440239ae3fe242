"""A Python child process whose last ``RESULT {json}`` line is the outcome, optionally with forced CPU devices.

JAX reads ``--xla_force_host_platform_device_count`` once, when its backend starts: the suite's own
process has one CPU device, so the tests that need several run their checks in a child.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys

PREFIX = "RESULT "


def env_with_devices(count: int) -> dict[str, str]:
    """This process's environment with ``count`` CPU devices added to ``XLA_FLAGS``."""
    env = dict(os.environ)
    env["XLA_FLAGS"] = f"{env.get('XLA_FLAGS', '')} --xla_force_host_platform_device_count={count}".strip()
    return env


def result(stdout: str) -> dict:
    """The JSON of the line the child printed as ``RESULT {json}``."""
    line = next(x for x in stdout.splitlines() if x.startswith(PREFIX))
    return json.loads(line[len(PREFIX) :])


def run(code: str, devices: int, timeout: float) -> dict:
    """Run ``code`` with ``devices`` CPU devices; its result (the child's error output on failure)."""
    proc = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=timeout, env=env_with_devices(devices)
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    return result(proc.stdout)
