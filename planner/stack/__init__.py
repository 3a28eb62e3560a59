"""A stack of the programs on one machine (``rover stack up``, ``rover demo``):
child processes, ROS 2 domains, stall reports (docs/commands.md).
"""
