"""Strings that reach generated C code: identifiers and comment text.

Model names and symbol names are free text chosen by a user (or read from a model
file), and they end up in generated C: in function names, and in the comment at the
top of an exported header.  Every such string goes through one of two functions here:

- :func:`c_identifier` turns any text into a name that both CasADi and C accept
  (ASCII letters, digits and single underscores, starting with a letter, bounded
  length), made unique by a hash of the original text;
- :func:`comment_text` turns any text into a line that cannot leave a ``/* ... */``
  comment: no ``*/``, no ``/*``, no newline, no trigraph, no non-ASCII character, and
  no backslash at the end of a line.

The name a user wrote is kept as written everywhere else (``Model.name``, reports).
"""

from __future__ import annotations

import hashlib
import re
import unicodedata

__all__ = ["c_identifier", "comment_text", "is_casadi_name"]

#: What CasADi accepts as a Function name (function_internal.cpp, "Function name is
#: not valid"): a letter, then letters, digits or non-consecutive underscores.  A
#: trailing underscore is refused too, because symmon appends "_suffix" to names.
_CASADI_NAME = re.compile(r"^[A-Za-z][A-Za-z0-9]*(?:_[A-Za-z0-9]+)*$")
#: Longest readable part kept from a free-text name (the hash keeps it unique).
MAX_STEM = 40
#: Hex digits of sha256 appended to make sanitised names unique.
HASH_DIGITS = 8


def is_casadi_name(name: str, max_len: int = 63) -> bool:
    """True if ``name`` is a valid C identifier that CasADi also accepts as a Function
    name and to which ``"_g"``-like suffixes can be appended."""
    return isinstance(name, str) and len(name) <= max_len and bool(_CASADI_NAME.match(name)) \
        and not name.lower().startswith("casadi") and name not in ("null", "jac", "hess")


def c_identifier(text: str, *, hashed: bool = True, max_len: int = MAX_STEM) -> str:
    """A C identifier made from any text.

    Accents are dropped (NFKD), every run of other characters becomes one underscore,
    leading and trailing underscores are removed, a leading digit gets an ``m``
    prefix, and the result is cut to ``max_len`` characters.

    Parameters
    ----------
    text : str
        Any text (a model name as the user wrote it).
    hashed : bool, default True
        Append ``_`` and 8 hex digits of sha256(text), so that different texts give
        different identifiers ("a b" and "a_b", or two long names with the same
        start).  Without it the identifier is only readable, not unique.
    max_len : int
        Bound on the readable part.

    Returns
    -------
    str
        Matches ``[A-Za-z][A-Za-z0-9]*(_[A-Za-z0-9]+)*``: valid in C and as a CasADi
        Function name, and still valid after appending ``_suffix``.

    Examples
    --------
    >>> c_identifier("polar (rad)", hashed=False), c_identifier("range & bearing", hashed=False)
    ('polar_rad', 'range_bearing')
    >>> c_identifier("a_")[:2], len(c_identifier("a_"))
    ('a_', 10)
    """
    text = str(text)
    ascii_text = unicodedata.normalize("NFKD", text).encode("ascii", "ignore").decode("ascii")
    stem = re.sub(r"[^A-Za-z0-9]+", "_", ascii_text).strip("_")
    if not stem or not stem[0].isalpha() or stem.lower().startswith("casadi"):
        # CasADi names start with a letter; "casadi*" is CasADi's own namespace in C.
        stem = "m_" + stem if stem else "model"
    stem = stem[:max_len].rstrip("_")
    if hashed:
        stem += "_" + hashlib.sha256(text.encode("utf-8", "surrogatepass")).hexdigest()[:HASH_DIGITS]
    return stem


def comment_text(text: str) -> str:
    """``text`` made safe inside a C block comment, on one line.

    Non-printable and non-ASCII characters become ``\\xNN``, ``\\uNNNN`` or
    ``\\UNNNNNNNN`` escapes (so a newline is the two characters ``\\n``), a backslash
    becomes ``\\\\``, and a backslash is put between the two characters of ``*/``,
    ``/*`` and ``??`` (a trigraph starts with ``??``; ``??/`` is a backslash).  The
    result contains none of those pairs, no newline and no character above 0x7e; a
    caller that quotes it (as ``export_c`` does) never ends a line with a backslash.

    Examples
    --------
    >>> comment_text("a */ b /* c ??/ d\\n")
    'a *\\\\/ b /\\\\* c ?\\\\?/ d\\\\n'
    """
    out: list[str] = []
    for ch in str(text):
        code = ord(ch)
        if ch == "\\":
            piece = "\\\\"
        elif 0x20 <= code < 0x7F:
            piece = ch
        elif code < 0x100:
            piece = {"\n": "\\n", "\r": "\\r", "\t": "\\t"}.get(ch, f"\\x{code:02x}")
        elif code < 0x10000:
            piece = f"\\u{code:04x}"
        else:
            piece = f"\\U{code:08x}"
        if out and out[-1][-1:] + piece[:1] in ("*/", "/*", "??"):
            out.append("\\")
        out.append(piece)
    return "".join(out)
