"""Benchmark suite of sbagents (``python -m benchmarks``): measured speed, written into ``BENCHMARKS.md``."""
