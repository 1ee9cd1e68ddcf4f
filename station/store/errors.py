"""Errors of the run store."""

from __future__ import annotations

from station.errors import StationError


class StoreError(StationError):
    """The run store refused an operation (unknown run, bad data, wrong store, ...)."""


class StoreUnavailable(StoreError, ConnectionError):
    """The central store cannot be reached or dropped the connection; the local store goes on."""


class StoreVersionError(StoreError):
    """The store's schema is newer than this code, or it is not a station store."""
