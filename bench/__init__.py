"""CapsuleRT benchmarks: ratios measured in one run, never timed assertions.

Run everything with ``python -m bench`` (``make bench``); ``--quick`` for a
small smoke run. Results print as a table and are written to
``bench/results/latest.json``.
"""
