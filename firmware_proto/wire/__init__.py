"""The motor controller's wire protocol (docs/protocol.md): the declarative spec
``protocol.toml``, the messages generated from it, serial framing and COBS, the CAN
identifier map, fault codes and counters, the code generators, test vectors, and the
C codec and firmware core (``c/``). Pure: no I/O, no threads (tests/test_layers.py).
"""
