"""Ground station: heuristic planner with repairs, orchestrator, gate client, executor
with drift control, link emulation and the operator CLI."""

__all__: list[str] = []
