"""No script answers the confirmations that guard real motion.

An armed run (``arm=True``: the configured device URLs, here the fake cell's
on loopback, which the station cannot tell from real hardware) refuses every
operator that is not a person, before the run is recorded or anything moves;
with a person at the terminal each confirmation is really asked. Dry runs on
the fakes may be answered by a script: yes to all, a callable, or an answer
file, whose "no" stops the run.
"""

import io
import json
import subprocess
import sys
from pathlib import Path

import pytest

from app.acceptance import Station
from app.cli import main
from station.errors import ConfigError, SafetyError
from app.terminal import InteractiveOperator
from station.runner import AnswerFileOperator
from station.store import RunStore
from tests.person import TYPED_YES, Terminal, person_typing_yes
from tests.pace import LOCKSTEP

ISO = {"cycles": 2, "vap_cycles": 2}


def _config_file(fake_cell, tmp_path):
    path = tmp_path / "station.json"
    path.write_text(json.dumps(fake_cell.config_dict(store_path="s.sqlite", report_dir="reports", iso9283=ISO)))
    return path


def _nothing_moved(fake_cell, tmp_path):
    """No run recorded and no program reached the controller's FTP folder."""
    db = tmp_path / "s.sqlite"
    if db.exists():
        with RunStore(db) as store:
            assert store.runs() == []
    assert list(fake_cell.controller.program_dir.iterdir()) == []
    assert fake_cell.controller.core.program is None


@pytest.mark.parametrize("scripted", ["callable", "answer file", "scripted yes"])
def test_an_armed_station_refuses_a_script_as_its_operator(fake_cell, tmp_path, scripted):
    cfg = _config_file(fake_cell, tmp_path)
    answers = tmp_path / "answers.txt"
    answers.write_text("yes\n" * 10)
    operator = {"callable": lambda message: True, "answer file": answers,
                "scripted yes": None}[scripted]
    if scripted == "scripted yes":  # the old API's forced answer, given explicitly
        from station.runner import ScriptedOperator
        operator = ScriptedOperator(True)
    with pytest.raises(SafetyError, match="needs a person"):
        Station.from_config(cfg, arm=True, operator=operator)
    _nothing_moved(fake_cell, tmp_path)


def test_station_run_refuses_yes_and_answers_with_arm(fake_cell, tmp_path, capsys):
    cfg = _config_file(fake_cell, tmp_path)
    answers = tmp_path / "answers.txt"
    answers.write_text("yes\n" * 10)
    for flags in (["--yes"], ["--answers", str(answers)]):
        assert main(["run", "iso9283", "--config", str(cfg), "--arm", "--quiet", *flags]) == 2
        assert "needs a person" in capsys.readouterr().err
    _nothing_moved(fake_cell, tmp_path)


def test_a_pipe_does_not_answer_an_armed_run(fake_cell, tmp_path):
    """``yes | station run iso9283 --arm``: standard input is a pipe, not a person; refused, nothing moved."""
    cfg = _config_file(fake_cell, tmp_path)
    root = Path(__file__).resolve().parents[2]
    argv = [sys.executable, "-m", "app.cli", "run", "iso9283", "--config", str(cfg), "--arm", "--quiet"]
    piped = subprocess.run(argv, cwd=root, input=TYPED_YES, capture_output=True, text=True, timeout=120)
    assert piped.returncode == 2, piped.stderr
    assert "standard input" in piped.stderr and "not a terminal" in piped.stderr
    _nothing_moved(fake_cell, tmp_path)
    # the prompts on a terminal while the answers come from a file: still not a person
    with Terminal() as term:
        answers = tmp_path / "yes.txt"
        answers.write_text(TYPED_YES)
        with answers.open() as stdin:
            filed = subprocess.run(argv, cwd=root, stdin=stdin, stderr=term.slave, stdout=subprocess.PIPE,
                                   timeout=120)
        shown = term.close()
    assert filed.returncode == 2 and "standard input is not a terminal" in shown, shown
    _nothing_moved(fake_cell, tmp_path)


def test_an_armed_station_refuses_an_operator_that_says_it_is_a_person(fake_cell, tmp_path):
    """No attribute or subclass makes a script a person: only the terminal operator on a tty, or the page."""
    cfg = _config_file(fake_cell, tmp_path)

    class SaysHuman:
        human = True

        def confirm(self, message):
            return True

    class TerminalLookalike(InteractiveOperator):
        human = True

        def confirm(self, message):
            return True

    with Terminal() as term:  # even on a real terminal, a subclass's own confirm is a script
        lookalike = TerminalLookalike(stdin=open(term.slave, closefd=False), stdout=open(term.slave, "w", closefd=False))
        for operator in (SaysHuman(), lookalike):
            with pytest.raises(SafetyError, match="needs a person"):
                Station.from_config(cfg, arm=True, operator=operator)
    # the terminal operator reading from a file or writing to one (a pipe, a log) is not at a terminal
    for stdin, stdout in ((io.StringIO(TYPED_YES), io.StringIO()), (io.StringIO(TYPED_YES), sys.__stderr__)):
        with pytest.raises(SafetyError, match="not a terminal"):
            Station.from_config(cfg, arm=True, operator=InteractiveOperator(stdin=stdin, stdout=stdout))
    _nothing_moved(fake_cell, tmp_path)


def test_a_terminal_swapped_for_a_pipe_mid_run_answers_nothing():
    """After the armed check, each prompt checks the terminal again: a stream swapped later is refused."""
    with Terminal() as term:
        person = term.operator()
        person.require_terminal()
        assert person.confirm("mount the reflector?") is True  # the typed yes, read on the terminal
        person.stdin = io.StringIO(TYPED_YES)
        with pytest.raises(SafetyError, match="standard input is not a terminal"):
            person.confirm("is the cell clear?")
        shown = term.close()  # joins the reader: everything the terminal showed
    assert "mount the reflector?" in shown and "cell clear" not in shown


@pytest.mark.slow
def test_an_armed_station_asks_the_person_every_confirmation(fake_cell, tmp_path):
    cfg = _config_file(fake_cell, tmp_path)
    person = person_typing_yes()
    station = Station.from_config(cfg, arm=True, operator=person)
    run = station.iso9283(cycles=2, vap_cycles=2, run_id="armed-1")
    assert run.status == "done", run.output
    asked = person.terminal.output()
    # the armed-run confirmation and the procedure's own (reflector, cell clear) reached the person
    assert "ARMED: real devices will move" in asked
    assert "clear" in asked.lower()
    with RunStore(tmp_path / "s.sqlite") as store:
        confirmed = [s.output.get("confirmed") for s in store.steps("armed-1")
                     if s.status == "done" and s.output and "confirmed" in s.output]
    assert confirmed and all(c in asked for c in confirmed)


def test_a_dry_run_stops_on_a_no_from_its_answer_file(tmp_path):
    answers = tmp_path / "answers.txt"
    answers.write_text("# first prompt: the reflector; then the cell\nyes\nclear = no\n")
    station = Station.fake(tmp_path, operator=answers, time_scale=LOCKSTEP)
    run = station.iso9283(cycles=2, vap_cycles=2, run_id="dry-no")
    assert run.status == "failed"
    assert run.passed is False
    assert station.operator.asked[-1][1] is False and "clear" in station.operator.asked[-1][0].lower()


def test_a_dry_run_takes_a_callable_and_logs_its_answers(tmp_path):
    seen = []
    station = Station.fake(tmp_path, operator=lambda message: seen.append(message) or True, time_scale=LOCKSTEP)
    run = station.iso9283(cycles=2, vap_cycles=2, run_id="dry-yes")
    assert run.status == "done", run.output
    assert seen and [m for m, _ in station.operator.asked] == seen


def test_an_answer_file_is_checked_line_by_line(tmp_path):
    bad = tmp_path / "bad.txt"
    bad.write_text("yes\nperhaps\n")
    with pytest.raises(ConfigError, match="line 2"):
        AnswerFileOperator(bad)
    short = tmp_path / "short.txt"
    short.write_text("yes\n")
    op = AnswerFileOperator(short)
    assert op.confirm("mount the reflector?") is True
    with pytest.raises(ConfigError, match="no answer left"):
        op.confirm("cell clear?")
    wrong = tmp_path / "wrong.txt"
    wrong.write_text("reflector = yes\n")
    with pytest.raises(ConfigError, match="expected a prompt with 'reflector'"):
        AnswerFileOperator(wrong).confirm("is the robot cell clear?")
