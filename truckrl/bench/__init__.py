"""Throughput benchmarks: ``truckrl bench <name> [options]``.

Each benchmark prints a table and writes JSON to ``outputs/bench/<name>-<timestamp>.json``.
Speed is shown here, never asserted in unit tests.
"""
