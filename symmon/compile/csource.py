"""symmon's own C: ``.c`` and ``.h`` files shipped beside the modules that build them.

Every C kernel of symmon (the random numbers, the vectorised row loops, the filter steps and
run loops, the particle and Gaussian-sum recursions, the Monte Carlo chunk, the exported
filter) is a file of the package, read once per process by :func:`c_file`.  A kernel's source
is that text, after the CasADi-generated C of its models where it calls them, and after a few
``#define`` lines (:func:`c_defines`) that give it its sizes and the names of the generated
functions: the source handed to :class:`~symmon.compile.ccache.NativeLibrary` is the final
text, so the cache key (a hash of it) covers the file's bytes.

A file that needs such definitions states them in a block guarded by its first macro, with
example values and the prototypes of what the assembled source puts before it, so that each
file compiles alone (``tests/compile/test_c_files.py`` compiles every file with
``-std=c99 -Wall -Wextra -Werror -pedantic``); in a kernel's source the block is skipped.
C that two kernels share is a file of its own that each includes (``#include "name.c"``):
:func:`c_source` puts its text in place of the line, as the preprocessor would.  C that is
put into other C word for word (symmon's products in CasADi's generated code, and CasADi's
own text they replace) is read by :func:`c_text`, after the file's guarded block.

The standalone C of :func:`symmon.export_c` is a template instead (it is read by people, and
built by their tool chains, not symmon's), a ``.c.in`` or ``.h.in`` file (not C alone: the
strict check skips it): :func:`choose` keeps or drops its optional parts ``@?FLAG:text?@``
(an argument ``const double *p`` where a model has parameters), and :func:`fill` replaces its
``@NAME@`` placeholders with checked C identifiers and integers, nothing else.
"""

from __future__ import annotations

import math
import re
from functools import lru_cache
from importlib import resources

__all__ = ["c_file", "c_text", "c_source", "c_defines", "fill", "choose", "C_IDENTIFIER"]

#: A C identifier (ASCII): what a name put into symmon's C may be.
C_IDENTIFIER = re.compile(r"[A-Za-z_][A-Za-z0-9_]*")
_INCLUDE = re.compile(r'^#include "([A-Za-z0-9_]+\.[ch])"\n', flags=re.M)
_PLACEHOLDER = re.compile(r"@([A-Za-z_][A-Za-z0-9_]*)@")
_OPTIONAL = re.compile(r"@\?([A-Za-z_][A-Za-z0-9_]*):(.*?)\?@", flags=re.S)


@lru_cache(maxsize=None)
def c_file(package: str, name: str) -> str:
    """The text of the C file ``name`` of the package ``package`` (``__package__`` of the
    module that builds it), read once per process; ``name`` may also be a template,
    ``.c.in`` or ``.h.in`` (see :func:`choose` and :func:`fill`).

    Raises
    ------
    ValueError
        If ``name`` is not a plain ``.c``, ``.h``, ``.c.in`` or ``.h.in`` file name.
    FileNotFoundError
        If the package has no such file (an installation without its package data).
    """
    if not re.fullmatch(r"[A-Za-z0-9_]+\.[ch](\.in)?", name):
        raise ValueError(f"name must be a .c, .h, .c.in or .h.in file name without a directory, got {name!r}")
    return resources.files(package).joinpath(name).read_text(encoding="utf-8")


def c_text(package: str, name: str) -> str:
    """The text of the C file ``name`` of ``package`` after its guarded block (its first
    ``#if`` line up to the next ``#endif`` line, and the comments before them): C that is put
    into other C word for word (CasADi's generated code), and compiles alone only with the
    block's definitions.

    Raises
    ------
    ValueError
        If ``name`` is not a plain file name, or the file has no ``#if`` block.
    """
    text = c_file(package, name)
    m = re.search(r"^#if.*?^#endif[^\n]*\n", text, flags=re.S | re.M)
    if m is None:
        raise ValueError(f"{name} has no guarded block (#if ... #endif) to skip")
    return text[m.end():]


def c_source(package: str, name: str) -> str:
    """The text of the C file ``name`` of ``package`` with each of its lines
    ``#include "OTHER"`` (a file of the same package, named without a directory) replaced by
    the text of that file, as the preprocessor would: C that two kernels share stays one
    file, and a file that includes it compiles alone.  (Includes with a directory, such as
    the ``../../compile/casadi_alone.h`` of a guarded block, are left as they are.)

    Raises
    ------
    ValueError
        If ``name`` or an included name is not a plain ``.c`` or ``.h`` file name.
    """
    return _INCLUDE.sub(lambda m: c_source(package, m.group(1)), c_file(package, name))


def _c_value(key: str, value: object) -> str:
    """The C text of one checked value (see :func:`c_defines`)."""
    if isinstance(value, bool):
        return "1" if value else "0"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        if not math.isfinite(value):
            raise ValueError(f"{key} must be finite, got {value!r}")
        return repr(value)  # the shortest text that reads back as the same double
    if isinstance(value, str):
        if not C_IDENTIFIER.fullmatch(value):
            raise ValueError(f"{key} must be a C identifier, got {value!r}")
        return value
    if isinstance(value, (tuple, list)):
        if not value:
            raise ValueError(f"{key} must not be empty (a C array needs an element)")
        return ", ".join(_c_value(key, v) for v in value)
    raise ValueError(f"{key} must be an int, a float, a C identifier or a sequence of them, "
                     f"got {type(value).__name__}")


def c_defines(**values: object) -> str:
    """``#define NAME VALUE`` lines, one per keyword, in the order given.

    A value is an int (a bool is 0 or 1), a finite float (its ``repr``, which C reads back as
    the same double), a C identifier, or a non-empty sequence of those (comma-separated: the
    elements of an array initialiser).  Nothing else can reach the C: no expression, no
    string, no newline.

    Raises
    ------
    ValueError
        If a name is not a C identifier or a value is none of the above.

    Examples
    --------
    >>> print(c_defines(PFK_NX=4, PFK_F="model_f", PFK_AX=(1, 0)), end="")
    #define PFK_NX 4
    #define PFK_F model_f
    #define PFK_AX 1, 0
    """
    lines = []
    for key, value in values.items():
        if not C_IDENTIFIER.fullmatch(key):
            raise ValueError(f"a macro name must be a C identifier, got {key!r}")
        lines.append(f"#define {key} {_c_value(key, value)}\n")
    return "".join(lines)


def fill(template: str, **values: object) -> str:
    """``template`` with each ``@NAME@`` replaced by the checked value of ``NAME`` (an int,
    or a C identifier; see :func:`c_defines`).

    Raises
    ------
    ValueError
        If a placeholder has no value, a value has no placeholder, or a value is not an
        int or a C identifier.

    Examples
    --------
    >>> fill("int @P@_n = @N@;", P="ekf_polar", N=3)
    'int ekf_polar_n = 3;'
    """
    text = {}
    for key, value in values.items():
        if isinstance(value, (float, tuple, list)):
            raise ValueError(f"{key} must be an int or a C identifier, got {value!r}")
        text[key] = _c_value(key, value)
    used = set(_PLACEHOLDER.findall(template))
    missing, unused = sorted(used - text.keys()), sorted(text.keys() - used)
    if missing:
        raise ValueError(f"no value for the placeholders {', '.join(missing)}")
    if unused:
        raise ValueError(f"no placeholder for the values {', '.join(unused)}")
    return _PLACEHOLDER.sub(lambda m: text[m.group(1)], template)


def choose(template: str, **flags: bool) -> str:
    """``template`` with each optional part ``@?FLAG:text?@`` replaced by ``text`` where the
    flag ``FLAG`` is true, and removed where it is false (``text`` may hold ``@NAME@``
    placeholders for :func:`fill`, and not ``?@``; parts do not nest).

    Raises
    ------
    ValueError
        If a part has no flag, a flag has no part, or a flag is not a bool.

    Examples
    --------
    >>> choose("int f(double *x@?P:, const double *p?@);", P=False)
    'int f(double *x);'
    >>> fill(choose("int @F@(double *x@?P:, const double *p?@);", P=True), F="kf_predict")
    'int kf_predict(double *x, const double *p);'
    """
    for key, value in flags.items():
        if not isinstance(value, bool):
            raise ValueError(f"{key} must be a bool, got {value!r}")
    used = set(m.group(1) for m in _OPTIONAL.finditer(template))
    missing, unused = sorted(used - flags.keys()), sorted(flags.keys() - used)
    if missing:
        raise ValueError(f"no flag for the optional parts {', '.join(missing)}")
    if unused:
        raise ValueError(f"no optional part for the flags {', '.join(unused)}")
    return _OPTIONAL.sub(lambda m: m.group(2) if flags[m.group(1)] else "", template)
