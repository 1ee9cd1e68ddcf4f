"""Text from files, names and people as the station shows it: on a terminal, in a record, in a message.

A name or a description comes from outside (a model file, a stop list, an
operator's form, ``--what``) and may carry control characters: an ANSI escape
that recolours or clears the terminal, a BEL, a NUL that XML 1.0 cannot hold.
:func:`shown` writes each of them visibly as Python does (``\\x1b``,
``\\x07``, ``\\u202e``), so the text stays readable and the record stays
well-formed; ``lines=True`` keeps tab and newline (a multi-line message).
:func:`quoted` is a value quoted in an error message, cut to a length.
"""

from __future__ import annotations

import re

#: C0 controls, DEL, C1 controls, and the bidirectional overrides that reorder what follows them
_CONTROL = re.compile("[\x00-\x1f\x7f-\x9f\u200e\u200f\u202a-\u202e\u2066-\u2069\u2028\u2029]")
_CONTROL_BUT_LINES = re.compile("[\x00-\x08\x0b-\x1f\x7f-\x9f\u200e\u200f\u202a-\u202e\u2066-\u2069\u2028\u2029]")
#: characters of a value an error message quotes
QUOTE_MOST = 80


def _visible(m: re.Match) -> str:
    c = ord(m.group())
    return f"\\x{c:02x}" if c < 0x100 else f"\\u{c:04x}"


def shown(value, most: int | None = None, *, lines: bool = False) -> str:
    """``value`` as text with its control characters escaped visibly; at most ``most`` characters of it (then
    ``...`` and the length). ``lines``: tab and newline stay (otherwise the text is one line)."""
    text = (_CONTROL_BUT_LINES if lines else _CONTROL).sub(_visible, str(value))
    if most is not None and len(text) > most:
        return f"{text[:max(0, most - 3)]}... ({len(text)} characters)"
    return text


def quoted(value, most: int = QUOTE_MOST) -> str:
    """``value`` quoted for an error message: escaped, at most ``most`` characters."""
    return "'" + shown(value, most) + "'"


__all__ = ["shown", "quoted", "QUOTE_MOST"]
