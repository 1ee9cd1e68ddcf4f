import os

import pytest

from tests.store.pgserver import PgServer, server_bin


@pytest.fixture(scope="session")
def pg_server():
    """A real PostgreSQL server on a private port and data directory, removed after the session."""
    if server_bin() is None:
        if os.geteuid() != 0:
            pytest.skip("no PostgreSQL server binaries and not root to install them (bash scripts/setup --tests as root)")
        pytest.fail("no PostgreSQL server binaries: scripts/setup --tests installs Debian's postgresql package as root")
    server = PgServer()
    yield server
    server.close()


@pytest.fixture
def pg_url(pg_server):
    """A fresh, empty database on the session's server."""
    return pg_server.create_db()
