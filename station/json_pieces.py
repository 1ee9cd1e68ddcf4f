"""JSON written in pieces: an object too large to build whole (100,000 poses' results) made a few members at a time.

:class:`Pieces` stands in a dict for a JSON object whose members are made on
demand, a batch at a time; :func:`dump_json` writes the dict to a file handle
as ``json.dumps(d)`` would write it with every :class:`Pieces` built whole (the
same text, character for character), holding one batch's members at a time.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Iterator


class Pieces:
    """A JSON object of ``n`` members, made by ``batches()`` as dicts of a few members each, in their order."""

    def __init__(self, n: int, batches: Callable[[], Iterator[dict]]):
        self.n = n
        self.batches = batches

    def __len__(self) -> int:
        return self.n

    def whole(self) -> dict:
        """Every member in one dict."""
        out: dict = {}
        for b in self.batches():
            out.update(b)
        return out


def _mark(k: int) -> str:
    return f"\x00pieces {k}\x00"  # no JSON value holds a NUL itself: json.dumps writes it as \u0000


def dump_json(fh, d: dict) -> None:
    """``json.dumps(d)`` (compact: no indentation) written to ``fh``, each :class:`Pieces` value of ``d``'s top
    level a batch at a time."""
    lazy = {k: v for k, v in d.items() if isinstance(v, Pieces)}
    if not lazy:
        fh.write(json.dumps(d))
        return
    skeleton = {k: (_mark(i) if k in lazy else v) for i, (k, v) in enumerate(d.items())}
    text = json.dumps(skeleton)
    at = 0
    for i, (k, v) in enumerate(d.items()):  # loop over the top level's members: the pieces in their places
        if k not in lazy:
            continue
        mark = json.dumps(_mark(i))
        j = text.index(mark, at)
        fh.write(text[at:j])
        fh.write("{")
        first = True
        for batch in v.batches():  # loop over the batches of members
            if batch:
                fh.write(("" if first else ", ") + json.dumps(batch)[1:-1])
                first = False
        fh.write("}")
        at = j + len(mark)
    fh.write(text[at:])
