"""Stable device names and CAN bring-up on the rover: the udev rules, the networkd file
and the bring-up scripts in this folder, and the tooling that finds, checks and installs
them (``rover devices``, ``rover udev``; udev/README.md).

- :mod:`udev.devices`: what is plugged in, and the names the rules give it;
- :mod:`udev.rules`: a reader and evaluator of the rules files;
- :mod:`udev.verify`: the rules checked by udev itself;
- :mod:`udev.install`: installing them (dry run, diff, reload);
- :mod:`udev.cli`: the ``rover devices`` and ``rover udev`` subcommands;
- :mod:`udev.errors`: the package's exception root, :class:`~udev.errors.UdevError`.

Rover-side set-up: only the standard library and pyserial; imports no other part.
"""
