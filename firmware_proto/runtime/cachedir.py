"""Where the project keeps what it builds outside a checkout: ``$XDG_CACHE_HOME/rover/NAME``,
else ``~/.cache/rover/NAME``, unless an environment variable names the directory itself
(the C firmware library and images: ``ROVER_FIRMWARE_CACHE``; the tests' C programs:
``ROVER_TEST_BUILD_CACHE``)."""

from __future__ import annotations

import os
from pathlib import Path

__all__ = ["rover_cache_dir"]


def rover_cache_dir(name: str, override_env: str) -> Path:
    """``$override_env`` if set and not empty, else the user's cache directory's
    ``rover/name`` (not created here)."""
    env = os.environ.get(override_env)
    if env:
        return Path(env)
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "rover" / name
