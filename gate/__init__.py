"""Simulation gate: HTTP /validate_plan playing command plans on the pymunk twin."""

__all__: list[str] = []
