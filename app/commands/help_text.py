"""Help texts from the commands' docstrings, without their markup (``code``, :mod:`name`) and without the
usage line argparse prints itself."""

from __future__ import annotations

import re

_ROLE = re.compile(r":(?:mod|func|class|meth|data|attr):`~?([^`]+)`")
_CODE = re.compile(r"``([^`]+)``")


def plain(text: str) -> str:
    """``text`` as a reader of ``--help`` should see it: markup gone, a leading ``station ...`` usage line dropped."""
    lines = text.strip("\n").splitlines()
    if lines and lines[0].strip().startswith("``station "):
        lines = lines[1:]
    out = "\n".join(lines)
    out = _ROLE.sub(r"\1", out)
    out = _CODE.sub(r"\1", out)
    return " ".join(out.split())
