"""Planning: the heuristic planner, the orchestrator and its repairs, the gate
client, and the thesis's planning experiment (docs/planner.md).
"""
