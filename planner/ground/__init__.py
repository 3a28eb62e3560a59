"""The ground station: the executor and drift control, missions, the link relay,
the operator's console and their commands (docs/ground.md).
"""
