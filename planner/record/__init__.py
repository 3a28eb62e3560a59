"""Recordings: MCAP missions, markers, the live Foxglove connection and the
mission picture (docs/view.md).
"""
