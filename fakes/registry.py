"""The fakes by name: one table, from the device table's rows (:data:`station.device_urls.SCHEMES`).

Each scheme's row names the fake that speaks its protocol (``fake``) and the
module that starts it (``fake_module``); :data:`FAKES` collects them, plus the
whole fake cell (``station``). ``station fakes serve NAME`` and the fake cells
(:mod:`fakes.cells`) start fakes through :func:`start_named`.

Every module listed exposes ``start_fake(world, *, host=None, port=None,
faults=None) -> handle`` with ``handle.endpoint`` (JSON-able) and
``handle.close()``; the scanner's hot-folder fake also needs its folder
(``start_fake(world, folder, faults=None)``), so it is started by the cells
that own a folder, not served on its own.
"""

from __future__ import annotations

import importlib
from types import ModuleType
from typing import Any

from station.device_urls import SCHEMES
from station.errors import ConfigError

#: fake name -> module that provides ``start_fake``
FAKES: dict[str, str] = {s.fake: s.fake_module for s in SCHEMES.values() if s.fake}
FAKES["station"] = "fakes.station"

#: fakes that ``station fakes serve`` can start with no more than a world (the scanner needs a folder)
SERVABLE: tuple[str, ...] = tuple(n for n in FAKES if n != "scanner")


def fake_module(name: str) -> ModuleType:
    """The module of the fake called ``name``."""
    if name not in FAKES:
        raise ConfigError(f"no fake called {name!r} (have {', '.join(sorted(FAKES))})")
    return importlib.import_module(FAKES[name])


def start_named(name: str, world, **kwargs) -> Any:
    """Start the fake called ``name`` around ``world``; ``kwargs`` go to its ``start_fake``."""
    return fake_module(name).start_fake(world, **kwargs)


def url_of(scheme: str, handle) -> str:
    """The device URL of a running fake for ``scheme`` (its endpoint in that scheme's grammar)."""
    url = getattr(handle, "url", None)
    if isinstance(url, str) and url.startswith(f"{scheme}://"):
        return url
    ep = handle.endpoint
    if "device" in ep:
        return f"{scheme}://{ep['device']}"
    if scheme == "ur":
        return f"ur://{ep['host']}"
    return f"{scheme}://{ep['host']}:{ep['port']}"


__all__ = ["FAKES", "SERVABLE", "fake_module", "start_named", "url_of"]
