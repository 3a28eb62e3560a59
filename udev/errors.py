"""Exceptions raised by :mod:`udev`.

Everything the device tooling raises on purpose derives from :class:`UdevError`::

    UdevError (RuntimeError)
     +-- udev.install.InstallError          an install was refused or failed
     +-- udev.verify.CheckUnavailableError  no way to check rules with udev here

Rules udev rejects are no exception but issues (:class:`udev.rules.Issue`).
"""

from __future__ import annotations

__all__ = ["UdevError"]


class UdevError(RuntimeError):
    """Root of the errors of the udev tooling (rules, devices, install)."""
