"""The operator's page: ``station serve`` (issue 16).

A local web server for one station. It drives the same application layer as
the CLI (:func:`station.assemble.run_procedure`), reads the same store, and
shows runs live through server-sent events. Modules, one job each:

* :mod:`station.web.live`: runs this server drives (thread, operator that
  waits for the page, pause/abort control);
* :mod:`station.web.state`: JSON snapshots of the station and of a run, read
  from the store (the one source of truth) plus what the live run adds;
* :mod:`station.web.security`: access token, CSRF token, Host check;
* :mod:`station.web.pages`: the HTML and the small script of the pages;
* :mod:`station.web.app`: the Starlette routes;
* :mod:`station.web.server`: uvicorn on a bound socket, started and stopped.
"""
