"""The package's version, in a module of its own: the command line reads it without importing
the package's face (symmon/__init__.py), which is above every layer."""

__version__ = "0.1.0"
