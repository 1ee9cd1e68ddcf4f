"""Which store a `station store` command asks: the station's own file or the central one."""

from __future__ import annotations

from pathlib import Path


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
