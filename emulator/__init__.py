"""Rover motor-controller emulator: the pymunk twin, the controller model, fault
injection, and front ends serving it over a pty or a python-can bus."""

__all__: list[str] = []
