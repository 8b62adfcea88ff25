"""Experiments and benchmarks: the paper's tables, the real-log benchmark, speed.

Benchmarks are not tests: they print and write JSON, and their figures go to
docs/RESULTS.md with the command that produced them.
"""
