"""`station ... --help` reads as plain text: no docstring markup, every option of every command explained,
every command described, and the analyses described at length."""

from __future__ import annotations

import argparse

from app.cli import build_parser



def _walk(p, path):
    yield path, p
    for a in p._actions:
        if isinstance(a, argparse._SubParsersAction):
            for name, sp in a.choices.items():
                yield from _walk(sp, path + [name])


def test_help_texts_are_plain_and_complete():
    seen = {}
    for path, p in _walk(build_parser(), []):
        text = p.format_help()
        seen[" ".join(path)] = p
        for mark in ("``", ":mod:", ":func:", ":class:"):
            assert mark not in text, (path, mark)
        lacking = [a.option_strings or [a.dest] for a in p._actions
                   if a.help is None and not isinstance(a, argparse._SubParsersAction)]
        assert not lacking, (path, lacking)
        if not any(isinstance(a, argparse._SubParsersAction) for a in p._actions):  # a command: it says what it does
            assert p.description, path
    for cmd in ("calibrate arm", "calibrate trailer", "diagnose arm", "diagnose trailer", "simulate arm",
                "simulate trailer", "analyze iso9283", "analyze hold", "init"):
        assert seen[cmd].description, cmd
