"""Benchmarks for ``asrmap bench``: one module per hot path.

A benchmark module defines ``NAME``, ``HELP`` and ``run(args) -> dict``; it prints its figures
(median, p99, throughput) as it goes and returns them for callers that want numbers. They use the
real recorded logs in ``../shared/data`` where the hot path consumes such data (see
:func:`service.datasets.data_dir`).
"""
