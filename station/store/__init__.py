"""The run store: one interface (:class:`RunStore`), a SQLite and a PostgreSQL backend.

``RunStore("station.sqlite")`` is the station's own store;
``RunStore("postgresql://station@db.plant/metrology?password_env=PGPASS")``
is the plant's central one. :func:`open_store` picks the store a config names.
"""

from station.store.errors import StoreError, StoreUnavailable, StoreVersionError
from station.store.runstore import RUN_TRANSITIONS, RunRecord, RunStore, StepRecord
from station.store.schema import SCHEMA_VERSION
from station.store_url import redacted

__all__ = ["RUN_TRANSITIONS", "RunRecord", "RunStore", "StepRecord", "SCHEMA_VERSION", "StoreError",
           "StoreUnavailable", "StoreVersionError", "redacted"]
