"""The benchmark suite's item modules (a package so that ``benchmarks/run.py`` imports them by name); run it with
``python benchmarks/run.py``."""
