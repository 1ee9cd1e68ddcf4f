"""The Starlette routes of the operator's page.

GET  ``/``                     station: devices, robots, runs with verdicts, start form
GET  ``/events``               station event stream (``runs``: the runs table, on change)
POST ``/runs``                 start a run (``procedure``, ``robot``, ``seed``)
GET  ``/runs/{id}``            run page
GET  ``/runs/{id}/state``      the run's snapshot as JSON
GET  ``/runs/{id}/events``     run event stream (``state``: the snapshot, on change)
POST ``/runs/{id}/answer``     answer the pending prompt (``prompt_id``, ``answer`` yes|no)
POST ``/runs/{id}/pause|continue|abort|resume``
GET  ``/runs/{id}/report``     the run's HTML report
GET  ``/robots/{serial}``      one robot's history across runs

Every POST needs the CSRF token (form field ``csrf`` or header
``X-CSRF-Token``); see :mod:`app.web.security` for the rest.
"""

from __future__ import annotations

import asyncio
import concurrent.futures
import json
import threading
import time
from collections.abc import AsyncIterator
from urllib.parse import parse_qs

from starlette.applications import Starlette
from starlette.requests import Request
from starlette.responses import FileResponse, HTMLResponse, JSONResponse, RedirectResponse, Response, StreamingResponse
from starlette.routing import Route

from station.characteristics import history_names
from station.errors import StationError
from station.store import RunStore, StoreError
from app.web import pages
from app.web.live import RunHub
from app.web.security import Guard
from app.web.state import report_path, run_state, station_state

#: how often an event stream looks for changes, s (the page updates at up to 4 Hz)
EVENT_PERIOD_S = 0.25
#: snapshots younger than this are shared between watchers and requests, s
SNAPSHOT_TTL_S = 0.24
#: a comment line this often keeps proxies and browsers from closing a quiet stream, s
KEEPALIVE_S = 15.0
#: largest POST body read, bytes (the page's forms hold a few short fields)
MAX_BODY_BYTES = 16 * 1024
#: most fields of a form
MAX_FORM_FIELDS = 20
#: a POST body must arrive within this many seconds
BODY_TIMEOUT_S = 10.0


def load_procedures(cfg) -> tuple[str, ...]:
    """The procedures ``cfg`` can run, their modules imported (seconds on a loaded host: numpy, scipy and the
    analyses behind them); :func:`create_app` calls it once, in a thread of its own, as the server starts."""
    from procedures.registry import runnable_procedures

    return tuple(runnable_procedures(cfg))


def _in_background(fn, *args) -> concurrent.futures.Future:
    """``fn(*args)`` in a daemon thread of its own; its result (or exception) in the returned future."""
    future: concurrent.futures.Future = concurrent.futures.Future()

    def work() -> None:
        try:
            future.set_result(fn(*args))
        except BaseException as exc:  # noqa: BLE001 - handed to whoever awaits the future
            future.set_exception(exc)

    threading.Thread(target=work, name="page-procedures", daemon=True).start()
    return future


def create_app(hub: RunHub, store: RunStore, guard: Guard) -> Starlette:
    """The app of one station: ``hub`` drives runs, ``store`` is read, ``guard`` checks requests.

    The event loop answers every connection, so no handler does slow work on it: the procedures' modules are
    imported once in a thread as the app is made (:func:`load_procedures`; the station page awaits it without
    holding the loop, and every other page is answered meanwhile), and the store's reads, the run's snapshot
    and a run's start (which may import a procedure's module, whose import lock would hold the loop) run in
    worker threads."""
    procedures = _in_background(load_procedures, hub.cfg)

    def _html(body: str, status: int = 200) -> HTMLResponse:
        return HTMLResponse(body, status_code=status, headers={"Cache-Control": "no-store",
                                                               "X-Frame-Options": "DENY"})

    async def _form(request: Request) -> dict[str, str] | Response:
        """The form of a POST, read only up to MAX_BODY_BYTES and MAX_FORM_FIELDS within BODY_TIMEOUT_S."""
        length = request.headers.get("content-length")
        if length is not None and (not length.isdigit() or int(length) > MAX_BODY_BYTES):
            return _html(pages.message_page("Refused", f"a form of at most {MAX_BODY_BYTES} bytes"), 413)
        chunks, size = [], 0

        async def read() -> bool:
            nonlocal size
            async for chunk in request.stream():
                size += len(chunk)
                if size > MAX_BODY_BYTES:
                    return False
                chunks.append(chunk)
            return True

        try:
            if not await asyncio.wait_for(read(), BODY_TIMEOUT_S):
                return _html(pages.message_page("Refused", f"a form of at most {MAX_BODY_BYTES} bytes"), 413)
        except asyncio.TimeoutError:
            return _html(pages.message_page("Refused", f"the form did not arrive within {BODY_TIMEOUT_S:g} s"), 408)
        raw = b"".join(chunks).decode("utf-8", "replace")
        try:
            fields = parse_qs(raw, keep_blank_values=True, max_num_fields=MAX_FORM_FIELDS)
        except ValueError:
            return _html(pages.message_page("Refused", f"a form of at most {MAX_FORM_FIELDS} fields"), 400)
        return {k: v[-1] for k, v in fields.items()}

    async def _checked_post(request: Request) -> tuple[dict[str, str], Response | None]:
        # the headers first (Origin): nothing of a refused request's body is read
        problem = guard.origin_problem(request.headers.get("host"), request.headers.get("origin"))
        if problem:
            return {}, _html(pages.message_page("Refused", problem), 403)
        form = await _form(request)
        if isinstance(form, Response):
            return {}, form
        token = form.get("csrf") or request.headers.get("x-csrf-token")
        problem = guard.post_problem(request.headers.get("host"), request.headers.get("origin"), token)
        if problem:
            return form, _html(pages.message_page("Refused", problem), 403)
        return form, None

    def _refused(exc: Exception, status: int = 409) -> Response:
        return _html(pages.message_page("Refused", _public(exc), guard.csrf_token), status)

    def _public(exc: Exception) -> str:
        """What the page may say of an error: never where the store lives."""
        text = str(exc)
        return text.replace(f" in {store.name}", "").replace(str(store.name), "the store")

    async def station(request: Request) -> Response:
        await asyncio.wrap_future(procedures)  # the registry's modules imported once, off the loop
        # the list itself is asked of the registry each time (cheap once imported; a registry changed since, e.g.
        # a procedure added by a test or a plugin, is offered), in a worker thread like every other read
        names = await asyncio.to_thread(load_procedures, hub.cfg)
        st = await asyncio.to_thread(station_state, hub.cfg, store, hub)
        return _html(pages.station_page(st, guard.csrf_token, list(names)))

    async def station_events(request: Request) -> Response:
        def snapshot() -> str:
            return pages.runs_table(station_state(hub.cfg, store, hub)["runs"])
        return _stream(request, "runs", snapshot, lambda: False)

    async def start_run(request: Request) -> Response:
        form, refused = await _checked_post(request)
        if refused:
            return refused
        try:
            seed = int(form.get("seed") or 0)
        except ValueError:
            return _refused(ValueError(f"seed must be an integer, got {form.get('seed')!r}"), 400)
        try:
            await asyncio.wrap_future(procedures)  # imported: the start below finds its modules loaded
            run_id = await asyncio.to_thread(lambda: hub.start(form.get("procedure", ""), form.get("robot") or "r1",
                                                               seed, existing={r.run_id for r in store.runs()}))
        except StationError as exc:
            return _refused(exc, 400 if isinstance(exc, ValueError) else 409)
        return RedirectResponse(f"/runs/{run_id}", status_code=303)

    cache: dict[str, tuple[float, dict]] = {}
    cache_lock = threading.Lock()
    snapshot_lock = threading.Lock()

    def _state(run_id: str) -> dict:
        """The run's snapshot; watchers within SNAPSHOT_TTL_S of each other share one (one store read)."""
        with snapshot_lock:  # watchers waking together wait for one snapshot instead of each making one
            now = time.monotonic()
            with cache_lock:
                hit = cache.get(run_id)
                if hit and now - hit[0] < SNAPSHOT_TTL_S:
                    return hit[1]
            st = run_state(store, run_id, hub.live(run_id))
            with cache_lock:
                cache[run_id] = (now, st)
                for key in [k for k, (t, _) in cache.items() if now - t > 10.0]:
                    del cache[key]
            return st

    async def run(request: Request) -> Response:
        run_id = request.path_params["run_id"]
        try:
            st = await asyncio.to_thread(_state, run_id)
        except StoreError as exc:
            return _refused(exc, 404)
        return _html(pages.run_page(st, guard.csrf_token))

    async def run_json(request: Request) -> Response:
        try:
            st = await asyncio.to_thread(_state, request.path_params["run_id"])
            return JSONResponse(json.loads(json.dumps(st, default=float)))
        except StoreError as exc:
            return JSONResponse({"error": _public(exc)}, status_code=404)

    async def run_events(request: Request) -> Response:
        run_id = request.path_params["run_id"]
        try:
            await asyncio.to_thread(_state, run_id)
        except StoreError as exc:
            return _refused(exc, 404)
        return _stream(request, "state", lambda: json.dumps(_state(run_id), default=float), lambda: False)

    def _action(name: str):
        async def act(request: Request) -> Response:
            form, refused = await _checked_post(request)
            if refused:
                return refused
            run_id = request.path_params["run_id"]
            try:
                if name == "answer":
                    answer = form.get("answer")
                    if answer not in ("yes", "no"):
                        raise _BadInput(f"answer must be 'yes' or 'no', got {answer!r}")
                    try:
                        prompt_id = int(form.get("prompt_id", ""))
                    except ValueError:
                        raise _BadInput(f"prompt_id must be an integer, got {form.get('prompt_id')!r}") from None
                    hub.answer(run_id, prompt_id, answer == "yes")
                elif name == "pause":
                    hub.pause(run_id)
                elif name == "continue":
                    hub.proceed(run_id)
                elif name == "abort":
                    hub.abort(run_id)
                elif name == "resume":
                    rec = store.run(run_id)
                    if rec.status not in ("failed", "aborted"):
                        raise _BadState(f"run {run_id} is {rec.status}; only a failed or aborted run is resumed "
                                        "here (a run left 'running' by a dead process: `station run --resume`)")
                    hub.resume(run_id)
            except StoreError as exc:
                return _refused(exc, 404)
            except _BadInput as exc:
                return _refused(exc, 400)
            except (StationError, _BadState) as exc:
                return _refused(exc, 409)
            finally:
                with cache_lock:  # the next snapshot shows the action's effect
                    cache.pop(run_id, None)
            return RedirectResponse(f"/runs/{run_id}", status_code=303)
        return act

    async def report(request: Request) -> Response:
        run_id = request.path_params["run_id"]
        try:
            path = report_path(await asyncio.to_thread(store.steps, run_id))
        except StoreError as exc:
            return _refused(exc, 404)
        if path is None:
            return _refused(StoreError(f"run {run_id} has no report (yet)"), 404)
        return FileResponse(path, media_type="text/html")

    async def robot(request: Request) -> Response:
        serial = request.path_params["serial"]

        def page() -> str:
            names = history_names()
            history = {name: store.history(serial, name) for name in names}
            models = store.robot_models(serial)
            overhauls = store.overhauls(serial=serial) if len(models) == 1 else []
            return pages.robot_page(serial, list(names), history, guard.csrf_token, overhauls)

        return _html(await asyncio.to_thread(page))

    async def record_overhaul(request: Request) -> Response:
        """An overhaul of the robot recorded from its page (as ``station store overhaul`` does)."""
        from station.fleet.questions import parse_when

        serial = request.path_params["serial"]
        form, refused = await _checked_post(request)
        if refused:
            return refused
        try:
            at = parse_when(form.get("date", ""), "the overhaul's date")
            model, serial = store.resolve_robot(serial, form.get("model") or None)
            store.record_overhaul(model, serial, at, form.get("what", ""), ticket=(form.get("ticket") or "").strip()
                                  or None, station=hub.cfg.station.name)
        except StationError as exc:
            return _refused(exc, 400)
        return RedirectResponse(f"/robots/{serial}", status_code=303)

    routes = [
        Route("/", station), Route("/events", station_events),
        Route("/runs", start_run, methods=["POST"]),
        Route("/runs/{run_id}", run), Route("/runs/{run_id}/state", run_json),
        Route("/runs/{run_id}/events", run_events), Route("/runs/{run_id}/report", report),
        Route("/robots/{serial}", robot), Route("/robots/{serial}/overhauls", record_overhaul, methods=["POST"]),
    ] + [Route(f"/runs/{{run_id}}/{name}", _action(name), methods=["POST"])
         for name in ("answer", "pause", "continue", "abort", "resume")]
    app = Starlette(routes=routes)
    return _Gate(app, guard)


class _BadInput(ValueError):
    pass


class _BadState(RuntimeError):
    pass


def _stream(request: Request, event: str, snapshot, stop) -> StreamingResponse:
    """Server-sent events: ``event`` with ``snapshot()`` whenever it changes (checked every EVENT_PERIOD_S)."""

    async def gen() -> AsyncIterator[str]:
        last = None
        quiet = 0.0
        while not await request.is_disconnected():
            data = await asyncio.to_thread(snapshot)
            if data != last:
                last = data
                quiet = 0.0
                yield f"event: {event}\ndata: " + data.replace("\n", "\ndata: ") + "\n\n"
            elif quiet >= KEEPALIVE_S:
                quiet = 0.0
                yield ": keepalive\n\n"
            if stop():
                return
            # on the period's ticks of the monotonic clock: every watcher wakes together and shares a snapshot
            await asyncio.sleep(EVENT_PERIOD_S - time.monotonic() % EVENT_PERIOD_S)
            quiet += EVENT_PERIOD_S

    return StreamingResponse(gen(), media_type="text/event-stream",
                             headers={"Cache-Control": "no-store", "X-Accel-Buffering": "no"})


class _Gate:
    """ASGI wrapper: the Host check on loopback, the access token elsewhere (see :mod:`app.web.security`)."""

    def __init__(self, app, guard: Guard) -> None:
        self.app = app
        self.guard = guard

    async def __call__(self, scope, receive, send) -> None:
        if scope["type"] != "http":
            return await self.app(scope, receive, send)
        request = Request(scope)
        if not self.guard.host_ok(request.headers.get("host")):
            return await HTMLResponse("unknown Host header", status_code=421)(scope, receive, send)
        if not self.guard.access_ok(request.cookies.get(self.guard.cookie_name)):
            token = request.query_params.get("token")
            if self.guard.access_from_query(token) and request.method == "GET":
                resp = RedirectResponse(request.url.path, status_code=303)
                resp.set_cookie(self.guard.cookie_name, token, httponly=True, samesite="strict")
                return await resp(scope, receive, send)
            msg = "this station needs the access token printed by `station serve` (open the URL it printed)"
            return await HTMLResponse(msg, status_code=401)(scope, receive, send)
        return await self.app(scope, receive, send)
