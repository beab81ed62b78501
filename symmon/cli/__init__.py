"""The ``symmon`` command (docs/reference/cli.md): :mod:`.parser` (options, checks, parser and
:func:`main`), :mod:`.commands` (one function per subcommand), :mod:`.output` (JSON, tables,
plots)."""

from .parser import main as main

__all__ = ["main"]
