"""JSON written in pieces: an object too large to build whole (100,000 poses' results) made a few members at a time.

:class:`Pieces` stands in a dict for a JSON object whose members are made on
demand, a batch at a time, each as its key and the JSON text of its value;
:func:`dump_json` writes the dict to a file handle as ``json.dumps(d)`` would
write it with every :class:`Pieces` built whole (the same text, character for
character), holding one batch's members at a time.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Iterator
from json.encoder import encode_basestring_ascii


class Pieces:
    """A JSON object of ``n`` members, made by ``batches()`` as lists of ``(key, JSON text of the value)``, in order."""

    def __init__(self, n: int, batches: Callable[[], Iterator[list[tuple[str, str]]]]):
        self.n = n
        self.batches = batches

    def __len__(self) -> int:
        return self.n

    def whole(self) -> dict:
        """Every member in one dict (the values read back from their text: the same numbers)."""
        return {k: json.loads(t) for b in self.batches() for k, t in b}


def _mark(k: int) -> str:
    return f"\x00pieces {k}\x00"  # no JSON text holds a NUL itself: json.dumps writes it as \u0000


def dump_json(fh, d: dict) -> None:
    """``json.dumps(d)`` (compact: no indentation) written to ``fh``, each :class:`Pieces` value of ``d``'s top
    level a batch at a time."""
    lazy = {k for k, v in d.items() if isinstance(v, Pieces)}
    if not lazy:
        fh.write(json.dumps(d))
        return
    text = json.dumps({k: (_mark(i) if k in lazy else v) for i, (k, v) in enumerate(d.items())})
    at = 0
    for i, (k, v) in enumerate(d.items()):  # loop over the top level's members: the pieces in their places
        if k not in lazy:
            continue
        mark = json.dumps(_mark(i))
        j = text.index(mark, at)
        fh.write(text[at:j] + "{")
        sep = ""
        for batch in v.batches():  # loop over the batches of members
            if batch:
                fh.write(sep + ", ".join(f"{encode_basestring_ascii(key)}: {value}" for key, value in batch))
                sep = ", "
        fh.write("}")
        at = j + len(mark)
    fh.write(text[at:])
