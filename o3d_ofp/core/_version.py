"""The package's version, in the lowest layer so that every layer may read it."""

#: The package's version (PEP 440); equal to pyproject.toml's (tests/test_architecture.py checks).
__version__ = "0.1.0"
