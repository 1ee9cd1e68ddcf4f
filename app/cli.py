"""`station` command line: dispatches to one module per command group.

Each group lives in ``app/commands/<group>.py`` and exposes
``register(subparsers)`` which adds its sub-parser and sets ``func`` (a callable
taking the parsed namespace and returning an exit code).
"""

from __future__ import annotations

import argparse
import importlib
import sys

from station.errors import StationError
from station.shown import shown

#: command groups, in the order ``station --help`` lists them
GROUPS = ("init", "demo", "run", "serve", "store", "simulate", "analyze", "calibrate", "diagnose", "predict",
          "compensate", "fakes")


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="station", description="The robot metrology station: ISO 9283 tests, arm and trailer calibration, "
                                    "diagnosis of the simulation, on real devices (--arm) or their fakes.")
    sub = parser.add_subparsers(dest="group", metavar="COMMAND")
    for name in GROUPS:
        importlib.import_module(f"app.commands.{name}").register(sub)
    _describe_from_help(sub)
    return parser


def _describe_from_help(sub: argparse._SubParsersAction) -> None:
    """A command registered with a one-line help and no description shows that line under its own --help."""
    helps = {a.dest: a.help for a in sub._choices_actions}
    for name, p in sub.choices.items():
        if not p.description and helps.get(name):
            p.description = helps[name][0].upper() + helps[name][1:] + "."
        for a in p._actions:
            if isinstance(a, argparse._SubParsersAction):
                _describe_from_help(a)


class _ShownStream:
    """The terminal as a command writes to it: control characters in what it prints (a model, pose or operator
    name, an overhaul's text) arrive escaped (``\\x1b``), never as escapes that recolour, clear or retitle it."""

    def __init__(self, raw) -> None:
        self._raw = raw
        self.unscreened = raw  # for the progress bar's own escapes (station.runner), which screens its text

    def write(self, text: str) -> int:
        self._raw.write(shown(text, lines=True))
        return len(text)

    def __getattr__(self, name):
        return getattr(self._raw, name)


def main(argv: list[str] | None = None) -> int:
    out, err = sys.stdout, sys.stderr
    sys.stdout, sys.stderr = _ShownStream(out), _ShownStream(err)
    try:
        return _main(argv)
    finally:
        sys.stdout, sys.stderr = out, err


def _main(argv: list[str] | None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    try:
        return int(args.func(args) or 0)
    except StationError as exc:
        print(f"station: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("station: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:  # output piped into `head` and the like: not an error of ours
        import os

        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 0


if __name__ == "__main__":
    sys.exit(main())
