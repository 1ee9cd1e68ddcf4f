"""The operator's page: ``station serve`` (issue 16).

A local web server for one station. It drives the same application layer as
the CLI (:func:`app.assemble.run_procedure`), reads the same store, and
shows runs live through server-sent events. Modules, one job each:

* :mod:`app.web.live`: runs this server drives (thread, operator that
  waits for the page, pause/abort control);
* :mod:`app.web.state`: JSON snapshots of the station and of a run, read
  from the store (the one source of truth) plus what the live run adds;
* :mod:`app.web.security`: access token, CSRF token, Host check;
* :mod:`app.web.pages`: the HTML and the small script of the pages;
* :mod:`app.web.app`: the Starlette routes;
* :mod:`app.web.server`: uvicorn on a bound socket, started and stopped.
"""
