"""A test record per run: who and what, every measurement with its unit, limits and outcome, the report.

:func:`build` makes the record (a JSON-able dict) of one run;
:func:`write` writes it as ``RUN.record.json`` and as JUnit XML
(``RUN.junit.xml``) that plant CI systems show, and copies the HTML report
beside them (``RUN.report.html``, its SHA-256 in the record).

The JUnit XML follows the common JUnit schema: one ``<testsuite>`` per run
(its properties: the record's who and what, the verdict, the seed), one
``<testcase>`` for the run's verdict (``<failure>`` for FAIL and NOT DECIDED,
with ``type`` the verdict, ``<error type="ABORTED">`` for a run that did not
finish) and one per judged measurement (``classname`` the procedure,
``name`` ``POSE NAME``). Every measurement, judged or not, is on the run's
testcase as properties ``POSE/NAME`` (value), ``POSE/NAME.unit``,
``POSE/NAME.low``, ``POSE/NAME.high``, ``POSE/NAME.outcome`` (PASS, FAIL,
NOT DECIDED; empty when it has no limit) and ``POSE/NAME.marginal``.
"""

from __future__ import annotations

import hashlib
import json
import math
import shutil
import time
import xml.etree.ElementTree as ET
from pathlib import Path

from station.shown import shown
from station.verdict import Outcome, row_outcome

SCHEMA = "station-test-record/1"


def _num(x):
    return None if x is None or (isinstance(x, float) and not math.isfinite(x)) else float(x)


def measurement_rows(characteristics: list[dict], measurements: list[dict]) -> list[dict]:
    """Every number of the run: the procedure's characteristics (limit as high) and the plant's
    measurements (low, high, marginal), each with its outcome ("" where it has no limit)."""
    plant = {(m["pose"], m["name"]): m for m in measurements}
    rows = []
    for c in characteristics:
        m = plant.get((c["pose"], c["name"]))
        if m is not None:
            rows.append({"pose": m["pose"], "name": m["name"], "value": _num(m["value"]), "unit": m["unit"],
                         "low": _num(m["low"]), "high": _num(m["high"]), "outcome": m["outcome"],
                         "marginal": bool(m["marginal"]), "of": m.get("of"), "source": "plant"})
            continue
        o = row_outcome(c)
        rows.append({"pose": c["pose"], "name": c["name"], "value": _num(c["value"]), "unit": c["unit"],
                     "low": None, "high": _num(c.get("limit")),
                     "outcome": "" if o is None else o.value, "marginal": False,
                     "of": None, "source": "procedure"})
    return rows


def build(run) -> dict:
    """The record of ``run`` (a :class:`app.acceptance.AcceptanceRun` or anything with its attributes)."""
    subject = dict(getattr(run, "subject", {}) or {})
    who = {"robot": {k: subject.get(k) for k in ("model", "serial", "overhaul_state")},
           "station": subject.get("station"), **dict(getattr(run, "record", {}) or {})}
    for key in ("operator", "work_order", "overhaul_ticket"):
        who.setdefault(key, None)
    return {
        "schema": SCHEMA, "run_id": run.run_id, "procedure": run.procedure, "status": run.status,
        "verdict": str(run.verdict), "reasons": list(run.reasons), "exit_code": run.exit_code,
        "conformant": run.conformant, "seed": run.seed, "started_at": run.started_at,
        "finished_at": run.finished_at, "who": who,
        "measurements": measurement_rows(run.characteristics, list(getattr(run, "measurements", []) or [])),
        "report": run.report,
    }


def _text(v) -> str:
    if v is None:
        return ""
    if isinstance(v, float):
        return repr(v)
    return str(v)


def junit_xml(record: dict) -> ET.ElementTree:
    """The record as a JUnit XML tree (module docstring)."""
    verdict = Outcome.parse(record["verdict"])
    judged = [m for m in record["measurements"] if m["outcome"]]
    bad = [m for m in judged if m["outcome"] != Outcome.PASS.value]
    n_fail = (verdict in (Outcome.FAIL, Outcome.NOT_DECIDED)) + len(bad)
    n_err = int(verdict is Outcome.ABORTED)
    span = (record["finished_at"] or time.time()) - (record["started_at"] or time.time())
    root = ET.Element("testsuites", tests=str(1 + len(judged)), failures=str(n_fail), errors=str(n_err))
    suite = ET.SubElement(root, "testsuite", name=f"{record['procedure']} {record['run_id']}",
                          tests=str(1 + len(judged)), failures=str(n_fail), errors=str(n_err), skipped="0",
                          time=f"{max(span, 0.0):.3f}",
                          timestamp=time.strftime("%Y-%m-%dT%H:%M:%S", time.gmtime(record["started_at"] or 0)))
    props = ET.SubElement(suite, "properties")
    who = record["who"]
    flat = {f"robot.{k}": v for k, v in who["robot"].items()}
    flat.update({k: v for k, v in who.items() if k != "robot"})
    flat.update(run_id=record["run_id"], verdict=record["verdict"], seed=record["seed"],
                conformant=record["conformant"], report=record["report"])
    for k, v in flat.items():
        ET.SubElement(props, "property", name=str(k), value=_text(v))
    classname = f"{record['procedure']}.{who['robot'].get('serial') or 'run'}"
    case = ET.SubElement(suite, "testcase", classname=classname, name=f"{record['run_id']} verdict",
                         time=f"{max(span, 0.0):.3f}")
    cprops = ET.SubElement(case, "properties")
    for m in record["measurements"]:
        key = f"{m['pose']}/{m['name']}"
        for suffix, v in (("", m["value"]), (".unit", m["unit"]), (".low", m["low"]), (".high", m["high"]),
                          (".outcome", m["outcome"]), (".marginal", m["marginal"])):
            ET.SubElement(cprops, "property", name=key + suffix, value=_text(v))
    message = f"{verdict}: " + "; ".join(record["reasons"])
    if verdict is Outcome.ABORTED:
        ET.SubElement(case, "error", type=verdict.value, message=message).text = message
    elif verdict is not Outcome.PASS:
        ET.SubElement(case, "failure", type=verdict.value, message=message).text = message
    for m in judged:
        mc = ET.SubElement(suite, "testcase", classname=classname, name=f"{m['pose']} {m['name']}", time="0")
        mp = ET.SubElement(mc, "properties")
        for k, v in (("value", m["value"]), ("unit", m["unit"]), ("low", m["low"]), ("high", m["high"]),
                     ("outcome", m["outcome"]), ("marginal", m["marginal"])):
            ET.SubElement(mp, "property", name=k, value=_text(v))
        if m["outcome"] != Outcome.PASS.value:
            lim = " ".join(x for x in (f"low {m['low']:g}" if m["low"] is not None else "",
                                       f"high {m['high']:g}" if m["high"] is not None else "") if x)
            val = "not computed" if m["value"] is None else f"{m['value']:.6g} {m['unit']}"
            text = f"{m['outcome']}: {m['pose']} {m['name']} = {val} (limits {lim} {m['unit']})"
            ET.SubElement(mc, "failure", type=m["outcome"], message=text).text = text
    for el in root.iter():  # names and values come from outside: control characters are not XML 1.0
        for k, v in el.attrib.items():
            el.attrib[k] = shown(v)
        if el.text:
            el.text = shown(el.text, lines=True)
    ET.indent(root)
    return ET.ElementTree(root)


def write(record: dict, out_dir: str | Path) -> tuple[Path, Path]:
    """Write ``RUN.record.json`` and ``RUN.junit.xml`` (and copy the report beside them); their paths."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    rid = record["run_id"]
    record = dict(record)
    rep = record.get("report")
    if rep and Path(rep).is_file():
        dest = out / f"{rid}.report.html"
        if Path(rep).resolve() != dest.resolve():
            shutil.copyfile(rep, dest)
        record["report"] = {"path": dest.name, "source": str(rep),
                            "sha256": hashlib.sha256(dest.read_bytes()).hexdigest()}
    js = out / f"{rid}.record.json"
    js.write_text(json.dumps(record, indent=2), encoding="utf-8")
    xml = out / f"{rid}.junit.xml"
    junit_xml(record if not isinstance(record.get("report"), dict) else {**record, "report": record["report"]["path"]}
              ).write(xml, encoding="utf-8", xml_declaration=True)
    return js, xml


__all__ = ["build", "write", "junit_xml", "measurement_rows", "SCHEMA"]
