"""Stable device names and CAN bring-up on the rover: the udev rules, the networkd file
and the bring-up scripts in this folder, and the tooling that finds, checks and installs
them (``rover devices``, ``rover udev``; udev/README.md).

- :mod:`udev.devices`: what is plugged in (serial ports and CAN interfaces, with the
  names the rules give them) and which to use;
- :mod:`udev.rules`: a reader and evaluator of the rules files, so the rules are tested
  against recorded device properties;
- :mod:`udev.verify`: the rules checked by udev itself (``udevadm verify``, or udev's
  parser in a sandbox where udevadm has no ``verify``);
- :mod:`udev.install`: installing them (dry run, diff, reload);
- :mod:`udev.cli`: the ``rover devices`` and ``rover udev`` subcommands;
- :mod:`udev.errors`: the package's one exception root, :class:`~udev.errors.UdevError`.

Rover-side set-up, not the bridge: it needs only the standard library and pyserial's
port lister and imports none of the other parts.
"""
