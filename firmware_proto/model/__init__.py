"""The mission models every part shares: the command plan and its schema check, the
gate's verdict, poses and geometry, the world map and the rover description
(docs/architecture.md, Contracts). Pure: no I/O, no threads (tests/test_layers.py).
"""
