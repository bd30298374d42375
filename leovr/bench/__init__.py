"""Benchmarks: each writes a JSON file with the shape documented in docs/benchmarks.md."""
