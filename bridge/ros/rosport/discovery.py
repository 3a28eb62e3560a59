"""How fast our ROS 2 programs find each other: a Fast DDS participant profile of the
project's own (``fastdds_profile.xml``, docs/rosport.md "Discovery").

Fast DDS re-announces a participant every 3 s by default, and a program that starts beside
running ones often waits for the next of those before it matches them: 0.03-2.8 s here
(a ``rover status``, a ``rover stop``, a stack's onboard program waiting for the bridge).
The profile makes it every 0.5 s. :func:`use_fast_discovery` points Fast DDS at it through
its environment variables before a process creates its first participant, unless the
user has named a profile file of their own; child processes inherit it. Other middlewares
ignore it.
"""

from __future__ import annotations

import os
from collections.abc import MutableMapping
from pathlib import Path
from typing import Final

__all__ = ["ANNOUNCEMENT_PERIOD_S", "PROFILE", "PROFILE_ENVS", "use_fast_discovery"]

PROFILE: Final = Path(__file__).with_name("fastdds_profile.xml")
"""The participant profile (default profile: every participant of the process)."""
ANNOUNCEMENT_PERIOD_S: Final = 0.5
"""Its announcement period, s (Fast DDS's default: 3)."""
PROFILE_ENVS: Final = ("FASTRTPS_DEFAULT_PROFILES_FILE", "FASTDDS_DEFAULT_PROFILES_FILE")
"""Where Fast DDS 2 (Jazzy's) and Fast DDS 3 look for a profile file."""


def use_fast_discovery(environ: MutableMapping[str, str] | None = None) -> bool:
    """Point Fast DDS at :data:`PROFILE` in ``environ`` (default ``os.environ``), unless
    either of :data:`PROFILE_ENVS` is set already (the user's own profile wins) or the
    profile is missing from this installation (Fast DDS's defaults then, not an error
    from it in every program's output).

    Returns:
        True when this call set them.
    """
    env = os.environ if environ is None else environ
    if any(env.get(name) for name in PROFILE_ENVS) or not PROFILE.is_file():
        return False
    for name in PROFILE_ENVS:
        env[name] = str(PROFILE)
    return True
