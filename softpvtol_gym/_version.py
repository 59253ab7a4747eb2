"""The package's version, in one place: pyproject.toml reads it ([tool.setuptools.dynamic]), CITATION.cff
repeats it (tests/package/test_packaging.py checks both)."""

__version__ = "0.1.0"
