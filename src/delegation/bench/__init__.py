"""Benchmark harness: run allocation strategies on scenario files and generated scenarios.

The library returns records (``runner``, ``scale``), writes files (``report``, ``plots``) and
makes scenarios (``generate``); printing and progress bars belong to ``delegation.cli.bench``.
"""
