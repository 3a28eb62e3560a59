"""Benchmarks: each script prints a table of our figures beside a peer or a limit
measured in the same run."""
