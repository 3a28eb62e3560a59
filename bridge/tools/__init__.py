"""The lab's tools on the controller link: the conformance suite, the STOP bench,
traffic decoding and replay (docs/bench.md, docs/traffic-logs.md).
"""
