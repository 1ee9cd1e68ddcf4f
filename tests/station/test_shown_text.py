"""Control characters in names and texts from outside (issue 47 item 9): the JUnit XML stays well-formed, the
HTML report and the terminal show them escaped, an overhaul's text is bounded and listed on one line, and an
error message quotes a bad value cut short."""

from __future__ import annotations

import html
import re
import xml.dom.minidom
import xml.etree.ElementTree as ET

import pytest

from app.cli import main
from station.report import Report, render_html
from station.shown import QUOTE_MOST, shown
from station.run_record import junit_xml, write
from tests.store.helpers import station_config

#: what the hostile pass tried, and the rest of C0, DEL and C1
CONTROLS = ["\x00", "\x01", "\x1b", "\x07"] + [chr(c) for c in (*range(0x20), 0x7f, *range(0x80, 0xa0))]
RAW = re.compile("[\x00-\x08\x0b-\x1f\x7f-\x9f]")


def _nasty(rng, base: str) -> str:
    picks = [CONTROLS[int(i)] for i in rng.integers(0, len(CONTROLS), 4)]
    return base + "".join(picks[:2]) + "[31m" + base + "".join(picks[2:]) + "\x1b]0;pwned\x07"


def test_shown_escapes_every_control_character_visibly_and_keeps_the_rest():
    for c in CONTROLS:
        assert shown(f"a{c}b") == "a\\x%02xb" % ord(c)
    assert shown("Ünïcode ok, ∅ 🙂") == "Ünïcode ok, ∅ 🙂"
    assert shown("right\u202eleft") == "right\\u202eleft"
    assert shown("two\nlines\tand\x1b", lines=True) == "two\nlines\tand\\x1b"
    long = shown("x" * 5000, QUOTE_MOST)
    assert len(long) < QUOTE_MOST + 30 and "5000 characters" in long


def _record(rng):
    rows = [{"pose": _nasty(rng, "P1"), "name": _nasty(rng, "AP_mm"), "value": 6.2, "unit": "mm", "low": None,
             "high": 5.0, "outcome": "FAIL", "marginal": False, "of": None, "source": "procedure"}]
    return {"run_id": "r", "procedure": "iso9283", "verdict": "FAIL", "reasons": [_nasty(rng, "reason")],
            "seed": 3, "conformant": False, "report": None, "started_at": 0.0, "finished_at": 10.0,
            "who": {"robot": {"model": _nasty(rng, "m"), "serial": "s", "overhaul_state": "after"}, "station": "c",
                    "operator": _nasty(rng, "Kim"), "work_order": _nasty(rng, "WO"), "overhaul_ticket": None},
            "measurements": rows}


def test_the_junit_xml_stays_well_formed_with_control_characters_in_names(rng, tmp_path):
    record = _record(rng)
    _, path = write(record, tmp_path)
    root = ET.parse(path).getroot()  # expat: "not well-formed (invalid token)" before
    xml.dom.minidom.parse(str(path))
    text = path.read_text(encoding="utf-8")
    assert not RAW.search(text)
    case = root.find("testsuite").findall("testcase")[1]
    assert case.get("name") == shown(record["measurements"][0]["pose"]) + " " + shown(record["measurements"][0]["name"])
    props = {p.get("name"): p.get("value") for p in root.find("testsuite").find("properties")}
    assert shown(record["who"]["operator"]) in props.values()
    ET.fromstring(ET.tostring(junit_xml(record).getroot()))


def test_the_html_report_shows_control_characters_escaped(rng):
    pose, name = _nasty(rng, "P1"), _nasty(rng, "RP_mm")
    rows = [{"pose": pose, "name": name, "value": 0.2, "unit": "mm", "limit": 0.5, "passed": True}]
    text = render_html(Report(_nasty(rng, "run"), facts={"operator": _nasty(rng, "Kim")}, rows=rows,
                              notes=[_nasty(rng, "note")]))
    assert not RAW.search(text)
    assert "\\x1b]0;pwned\\x07" in text and html.escape(shown(pose, lines=True)) in text


@pytest.fixture
def cfg(tmp_path):
    return str(station_config(tmp_path, "cell-9", None))


def _overhaul(cfg, what, date="2026-01-02", serial="SN-1"):
    return main(["store", "overhaul", "--config", cfg, "--model", "ur5e", "--serial", serial, "--date", date,
                 "--what", what])


def test_an_overhauls_text_is_bounded_and_listed_on_one_line(cfg, capsys):
    assert _overhaul(cfg, "J2 gearbox " * 11_000) == 2  # 120 KB
    err = capsys.readouterr().err
    assert "at most 2000" in err and len(err) < 400
    assert _overhaul(cfg, "x" * 2001) == 2
    capsys.readouterr()
    assert _overhaul(cfg, "J2 gearbox replaced\n\x1b[2Jline two\r\x07", serial="SN-\x1b[31m2") == 0
    out = capsys.readouterr().out
    assert not RAW.search(out) and "\\x1b[2J" in out
    assert main(["store", "overhauls", "--config", cfg]) == 0
    out = capsys.readouterr().out
    assert out.count("\n") == 1 and not RAW.search(out)
    assert "J2 gearbox replaced\\x0a\\x1b[2Jline two\\x0d\\x07" in out and "SN-\\x1b[31m2" in out


def test_an_oversized_date_is_quoted_cut_short(cfg, capsys):
    assert _overhaul(cfg, "x", date="2026-01-02" + "9" * 50_000 + "\x1b[2J") == 2
    err = capsys.readouterr().err
    assert "--date" in err and "characters)" in err and len(err) < 250 and not RAW.search(err)


def test_names_from_a_file_reach_the_terminal_escaped(tmp_path, capsys):
    """A pose name with an ANSI escape in a stop list: the analysis prints it escaped (every command's output
    passes the same screen)."""
    stops = tmp_path / "stops.csv"
    rows = ["pose,cycle,x,y,z"] + [f"P\x1b[31m1,{c},{100 + 0.01 * c},{200},{300}" for c in range(1, 6)]
    stops.write_text("\n".join(rows) + "\n", encoding="utf-8")
    code = main(["analyze", "iso9283", "--stops", str(stops)])
    cap = capsys.readouterr()
    assert code in (0, 1, 3), cap.err
    assert "P\\x1b[31m1" in cap.out and not RAW.search(cap.out + cap.err)
