"""Exceptions raised by :mod:`udev`.

Everything the device tooling raises on purpose derives from :class:`UdevError`::

    UdevError (RuntimeError)
     +-- udev.install.InstallError       an install was refused or failed; the
     |                                   message says why and what to do
     +-- udev.verify.CheckUnavailableError  neither ``udevadm verify`` nor udev's
                                         parser in a sandbox can check rules here

Rules that udev rejects are no exception: they are issues (:class:`udev.rules.Issue`,
in :attr:`udev.verify.Verification.findings`), and the rules reader skips what it cannot
read (:attr:`udev.rules.RulesFile.issues`).
"""

from __future__ import annotations

__all__ = ["UdevError"]


class UdevError(RuntimeError):
    """Root of the errors of the udev tooling (rules, devices, install)."""
