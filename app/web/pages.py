"""The HTML of the pages (Jinja2 templates in ``app/web/templates``, autoescaped) and their small scripts
(no build step, no external files).

Pages are rendered on the server with the current snapshot, so they are
useful without the script; the script then follows the run's event stream
and redraws the parts that change. Every action is a form POST carrying the
CSRF token. Everything a template shows is escaped by the engine, its control
characters and bidirectional overrides first written visibly
(:func:`station.shown.shown`: ``\x1b``, ``\u202e``; the engine's ``finalize``);
the only markup passed through is matplotlib's SVG (its text escaped by
matplotlib, the overhauls' text in it screened here) and the run's state as
JSON for the script (``</`` broken up; the script screens what it shows the
same way).
"""

from __future__ import annotations

import functools
import json
import time

from markupsafe import Markup

from station.shown import shown


def _screened(value):
    """What a template shows: text with its control characters written visibly (a name from a file or a form
    may carry an ANSI escape, a BEL or a bidi override that reorders the line); markup as it is."""
    if isinstance(value, str) and not isinstance(value, Markup):
        return shown(value, lines=True)
    return value


@functools.lru_cache(maxsize=1)
def _env():
    from jinja2 import Environment, PackageLoader, StrictUndefined, select_autoescape

    env = Environment(loader=PackageLoader("app.web", "templates"), undefined=StrictUndefined,
                      autoescape=select_autoescape(["html"]), keep_trailing_newline=False, finalize=_screened)
    env.globals["style"] = _static(env, "style.css")
    return env


def _static(env, name: str) -> Markup:
    """A stylesheet or script of the templates' folder, verbatim (never read as a template)."""
    return Markup(env.loader.get_source(env, name)[0])


def _render(name: str, **context) -> str:
    return _env().get_template(name).render(**context)


def station_page(state: dict, csrf: str, procedures: list[str]) -> str:
    """Devices, robots, runs with verdicts, and the form that starts a run."""
    return _render("station.html", title=f"station {state['station']}", csrf=csrf, state=state,
                   procedures=procedures, runs=state["runs"], script=_static(_env(), "station.js"))


def runs_table(runs: list[dict]) -> str:
    return _render("runs_table.html", runs=runs)


def run_page(state: dict, csrf: str) -> str:
    """The run: its steps, the current one, the prompt, controls, results; redrawn from the event stream."""
    return _render("run.html", title=f"run {state['run_id']}", csrf=csrf, state=state,
                   state_json=Markup(_json_for_script(state)), script=_static(_env(), "run.js"))


def robot_page(serial: str, names: list[str], history: dict[str, list[dict]], csrf: str,
               overhauls: list[dict] | None = None) -> str:
    """One robot's characteristics across its finished runs: its recorded overhauls with the form that records
    one, and per characteristic a plot against the date (matplotlib, :func:`station.report.plot_history`) and
    its table."""
    from station.report import plot_history

    overhauls = overhauls or []
    events = [(o["at"], f"overhaul: {shown(o['what'], 60)}") for o in overhauls]
    histories = []
    for name in names:
        rows = history.get(name) or []
        if not rows:
            continue
        runs = worst_per_run(rows)
        svg = Markup(plot_history([r["created_at"] for r in runs], [r["value"] for r in runs],
                                  [r["limit"] for r in runs], [r["failed"] for r in runs], ylabel=shown(name),
                                  title=f"{shown(name)}: worst pose or path of each run", events=events)) if runs else ""
        for r in runs:
            r["date"] = time.strftime("%Y-%m-%d %H:%M", time.gmtime(r["created_at"]))
        histories.append({"name": name, "runs": runs, "svg": svg})
    listed = [{**o, "date": time.strftime("%Y-%m-%d %H:%M", time.localtime(o["at"]))} for o in overhauls]
    return _render("robot.html", title=f"robot {serial}", csrf=csrf, serial=serial, histories=histories,
                   any_history=any(history.values()), overhauls=listed)


def worst_per_run(rows: list[dict]) -> list[dict]:
    """Per finished run (in time order): the value of largest magnitude over its poses (sign kept, as limits
    bound ``|value|``), its limit, and whether any pose failed."""
    runs: dict[str, dict] = {}
    for r in rows:
        if r["value"] is None:
            continue
        cur = runs.setdefault(r["run_id"], {"run_id": r["run_id"], "created_at": r["created_at"], "value": r["value"],
                                            "limit": r["limit"], "state": r["overhaul_state"], "failed": False})
        if abs(r["value"]) > abs(cur["value"]):
            cur["value"] = r["value"]
        if r["limit"] is not None and (cur["limit"] is None or r["limit"] > cur["limit"]):
            cur["limit"] = r["limit"]
        cur["failed"] = cur["failed"] or r.get("passed") is False
    return list(runs.values())


def message_page(title: str, message: str, csrf: str = "") -> str:
    return _render("message.html", title=title, message=message, csrf=csrf)


def _json_for_script(state: dict) -> str:
    return json.dumps(state, default=float).replace("</", "<\\/")
