"""Benchmarks: ``python -m pedrl.bench`` (``make bench``)."""
