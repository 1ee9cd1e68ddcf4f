"""Which store a `station store` command asks: the station's own file, or the central one with ``--central``
(one rule for every store command, ``store fleet`` included)."""

from __future__ import annotations

from pathlib import Path

CONFIG_HELP = "the station config (TOML or JSON); its [station] store_path names the station's own store"
JSON_HELP = "print the answer as JSON instead of a table"
CENTRAL_HELP = "ask the central store ([station] store_url), not the station's own file (the default)"


def open_store(config: str, central: bool = False):
    """The station's own store, or with ``central`` the one ``store_url`` names."""
    from station.config import load_config
    from station.errors import ConfigError
    from station.store import RunStore

    cfg = load_config(config)
    if central:
        if not cfg.station.store_url:
            raise ConfigError(f"{config}: [station] store_url is not set: there is no central store to ask")
        return RunStore(cfg.station.store_url, station=cfg.station.name)
    return RunStore(cfg.station.store_file(Path(config).resolve().parent), station=cfg.station.name)
