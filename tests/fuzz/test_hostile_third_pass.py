"""Hostile input, third pass (issue 47, items 1-5): endless pipes, output paths, absurd models, simulate bounds.

Each test is an item's reproducer: on the commit the issue was filed against it filled the disk, replaced
a device node, believed a model no arm has, simulated for minutes, or ended in a traceback. Now each
ends in a clean refusal (exit 2, ``station: error:``) naming the input and the key or option, or in a
result. The hypothesis properties at the end cover model files, UR calibration files and every option
of ``station simulate``. Endless inputs come from a child process the test kills; every test's data is
capped by construction (the copy bound is lowered to a few MiB where a pipe is read).
"""

from __future__ import annotations

import atexit
import copy
import json
import math
import os
import shutil
import stat
import subprocess
import sys
import tempfile
import tracemalloc
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from app.cli import main
from station.errors import StationError
from station.models.arm_model_file import MAX_MODEL_BYTES, model_to_json, read_ur_calibration, resolve_arm
from station.models.robots import get_robot
from station.readers import once
from station.readers.out_files import output_file
from tests.hostile import refused as _refused

FUZZ = settings()  # the budget comes from the loaded profile (tests/fuzz/conftest.py)
ROOT = Path(__file__).resolve().parents[2]
STATION = [sys.executable, "-c", "import sys; from app.cli import main; sys.exit(main())"]
STOPS = "pose,cycle,x,y,z\n" + "".join(f"P{p},{c},{100 * p + 0.01 * c},{50 * p},{10 * c}\n"
                                       for c in range(1, 4) for p in range(1, 4))




@pytest.fixture
def private_tmp(tmp_path, monkeypatch) -> Path:
    """A TMPDIR of the test's own, so that a copy left behind would be seen."""
    d = tmp_path / "tmpdir"
    d.mkdir()
    monkeypatch.setenv("TMPDIR", str(d))
    monkeypatch.setattr(tempfile, "tempdir", str(d))
    return d


def _writer(target: str, data: bytes, head: bytes = b"") -> subprocess.Popen:
    """A child writing ``head``, then ``data`` (a short unit, repeated to 64 KB) into ``target`` (a FIFO) until killed.

    With no ``data`` it keeps the pipe open after the head without writing more (a reader waits on it).
    """
    code = ("import sys, time\nout = open(sys.argv[1], 'wb', buffering=0)\nb = bytes.fromhex(sys.argv[2]) * 65536\n"
            "try:\n    out.write(bytes.fromhex(sys.argv[3]))\n    while b:\n        out.write(b)\n"
            "    time.sleep(3600)\nexcept BrokenPipeError:\n    pass\n")
    return subprocess.Popen([sys.executable, "-c", code, target, data.hex(), head.hex()], stderr=subprocess.DEVNULL)


def _kill(child: subprocess.Popen) -> None:
    child.kill()
    child.wait(timeout=30)


# -- item 1: endless input ---------------------------------------------------------------------------------
@pytest.mark.parametrize("payload, needle", [(b"\0", "line 1: longer than 4096 characters"),
                                             (b"1,0,0,0\n", "more than 4 MiB from a pipe")])
def test_an_endless_pipe_is_refused_within_the_bound_and_leaves_no_copy(tmp_path, capsys, private_tmp,
                                                                        monkeypatch, payload, needle):
    monkeypatch.setattr(once, "MAX_COPY_BYTES", 4 << 20)
    fifo = tmp_path / "stream.fifo"
    os.mkfifo(fifo)
    child = _writer(str(fifo), payload)
    try:
        _refused(capsys, ["analyze", "hold", "--stream", str(fifo), "--rate-hz", "100"], f"{fifo}: ", needle)
    finally:
        _kill(child)
    assert list(private_tmp.iterdir()) == []


@pytest.mark.parametrize("argv, head, row, needle", [
    (["calibrate", "trailer", "--data"], b"t,kappa,psi\n", b"0.5,0.01,0.02\n", "more than 1 MiB from a pipe"),
    (["calibrate", "arm", "--robot", "rb5-850", "--data"], b"q1,q2,q3,q4,q5,q6,x,y,z\n", b"1,2,3,4,5,6,100,200,300\n",
     ":20002: more than 20000 poses"),
    (["analyze", "iso9283", "--stream", "/dev/null", "--poses"], b"", b"\0", "line 1: longer than 4096")])
def test_a_reader_that_reads_once_reads_the_pipe_itself_within_the_bound(tmp_path, capsys, private_tmp, monkeypatch,
                                                                        argv, head, row, needle):
    """No copy at all: an endless pipe of good rows ends at the byte bound (or the reader's row bound) first."""
    from station.readers import text

    monkeypatch.setattr(text, "MAX_PIPE_BYTES", 1 << 20)
    monkeypatch.setattr(once, "MAX_COPY_BYTES", 0)  # a copy would be refused at its first byte
    fifo = tmp_path / "data.fifo"
    os.mkfifo(fifo)
    child = _writer(str(fifo), row, head)
    try:
        _refused(capsys, argv + [str(fifo)], str(fifo), needle)
    finally:
        _kill(child)
    assert list(private_tmp.iterdir()) == []


def test_dev_zero_as_a_model_is_refused_after_a_bounded_read(capsys, tmp_path):
    tracemalloc.start()
    try:
        _refused(capsys, ["predict", "arm", "--model", "/dev/zero", "--joints", "q.csv", "--out",
                          str(tmp_path / "p.csv")], "/dev/zero: larger than")
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 4 * MAX_MODEL_BYTES
    assert not (tmp_path / "p.csv").exists()


def test_endless_standard_input_is_refused_and_a_killed_copy_leaves_nothing(tmp_path, private_tmp):
    """``station ... -`` fed forever: refused at the bound; killed while copying: no file left in TMPDIR."""
    env = {**os.environ, "TMPDIR": str(private_tmp), "PYTHONPATH": str(ROOT)}
    fifo = tmp_path / "in.fifo"
    os.mkfifo(fifo)
    # the model from standard input: one bounded read, no copy at all
    child = _writer(str(fifo), b"0")
    try:
        with open(fifo, "rb") as src:
            r = subprocess.run(STATION + ["predict", "arm", "--model", "-", "--joints", "q.csv", "--out",
                                          str(tmp_path / "p.csv")], stdin=src, env=env, capture_output=True,
                               text=True, timeout=60)
    finally:
        _kill(child)
    assert r.returncode == 2 and "<stdin>: larger than" in r.stderr and "Traceback" not in r.stderr, r.stderr
    # a stream from standard input, killed while it is being copied (the pipe stays open: the copy waits on it)
    os.unlink(fifo)
    os.mkfifo(fifo)
    child = _writer(str(fifo), b"", b"t,x,y,z\n" + b"1,0,0,0\n" * 1000)
    try:
        with open(fifo, "rb") as src:
            proc = subprocess.Popen(STATION + ["analyze", "hold", "--stream", "-", "--rate-hz", "100"], stdin=src,
                                    env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
        try:
            copying = _wait_for_copy(proc.pid)
            assert list(private_tmp.iterdir()) == []  # the copy has no name, even while it is written
            proc.kill()
        finally:
            proc.kill()
            proc.wait(timeout=30)
    finally:
        _kill(child)
    assert copying, "the copy was never seen"
    assert list(private_tmp.iterdir()) == []


def _wait_for_copy(pid: int) -> bool:
    """True once process ``pid`` holds its (unlinked) copy of standard input open."""
    import time

    deadline = time.monotonic() + 60
    while time.monotonic() < deadline:
        try:
            fds = os.listdir(f"/proc/{pid}/fd")
        except FileNotFoundError:
            return False
        for fd in fds:
            try:
                if "station-input-" in os.readlink(f"/proc/{pid}/fd/{fd}"):
                    return True
            except OSError:
                continue
        time.sleep(0.05)
    return False


@pytest.mark.parametrize("chunk", [7, 4096, 1 << 20])
def test_the_copy_names_the_first_overlong_line_however_the_bytes_arrive(monkeypatch, rng, chunk):
    import io

    monkeypatch.setattr(once, "_CHUNK", chunk)
    good = int(rng.integers(1, 3000))
    data = b"1,0,0,0\n" * good + b"x" * (4 * 4096 + 10)
    with pytest.raises(StationError, match=rf"^<in>: line {good + 1}: longer than 4096 characters$"):
        once.copy_bounded(io.BytesIO(data), io.BytesIO(), "<in>", 1 << 30)
    whole = b"1,0,0,0\n" * good + b"y" * 4000 + b"\n"
    out = io.BytesIO()
    assert once.copy_bounded(io.BytesIO(whole), out, "<in>", 1 << 30) == len(whole) and out.getvalue() == whole


def test_a_regular_file_is_read_where_it_lies(tmp_path):
    f = tmp_path / "s.csv"
    f.write_text("t,x,y,z\n")
    with once.regular_file(f) as (real, shown):
        assert real == f and shown == str(f)


@pytest.mark.parametrize("argv", [["run", "iso9283", "--config", "/dev/zero"], ["store", "runs", "--config", "/dev/zero"]])
def test_dev_zero_as_a_config_is_refused_after_a_bounded_read(capsys, argv):
    _refused(capsys, argv, "/dev/zero: larger than")


def test_dev_zero_as_an_answer_file_is_refused(tmp_path, capsys):
    from station.errors import ConfigError
    from station.runner import AnswerFileOperator

    with pytest.raises(ConfigError, match="answer file /dev/zero: cannot read it .*larger than"):
        AnswerFileOperator("/dev/zero")


# -- item 2: output paths ----------------------------------------------------------------------------------
def _output_cases(tmp: Path):
    """(argv with OUT in the place of the output path, option): every output path option of the command line."""
    d = str(tmp / "missing-input.csv")
    stops = tmp / "stops.csv"
    stops.write_text(STOPS)
    cfg = str(tmp / "station.toml")
    return [
        (["init", "--force", "--out", "OUT"], "--out"),
        (["analyze", "iso9283", "--stops", str(stops), "--json", "OUT"], "--json"),
        (["analyze", "hold", "--stream", d, "--json", "OUT"], "--json"),
        (["calibrate", "trailer", "--data", d, "--json", "OUT"], "--json"),
        (["calibrate", "arm", "--robot", "rb5-850", "--data", d, "--json", "OUT"], "--json"),
        (["calibrate", "arm", "--robot", "rb5-850", "--data", d, "--report", "OUT"], "--report"),
        (["calibrate", "arm", "--robot", "ur5e", "--data", d, "--ur-deltas", "OUT"], "--ur-deltas"),
        (["diagnose", "arm", "--robot", "rb5-850", "--data", d, "--json", "OUT"], "--json"),
        (["diagnose", "arm", "--robot", "rb5-850", "--data", d, "--report", "OUT"], "--report"),
        (["diagnose", "arm", "--robot", "rb5-850", "--data", d, "--model-out", "OUT"], "--model-out"),
        (["diagnose", "trailer", "--l1", "1", "--l2", "2", "--data", d, "--json", "OUT"], "--json"),
        (["diagnose", "trailer", "--l1", "1", "--l2", "2", "--data", d, "--report", "OUT"], "--report"),
        (["predict", "arm", "--model", "rb5-850", "--joints", d, "--out", "OUT"], "--out"),
        (["compensate", "arm", "--model", "rb5-850", "--targets", d, "--out", "OUT"], "--out"),
        (["store", "fleet", "page", "--config", cfg, "--out", "OUT"], "--out"),
        (["run", "iso9283", "--config", cfg, "--json", "OUT"], "--json"),
        (["demo", "--json", "OUT", "--out", str(tmp / "demo")], "--json"),
    ]


_DIR_CASES = [(["simulate", sub, "--out", "OUT"], "--out") for sub in ("iso9283", "arm", "trailer", "hold")] + [
    (["store", "export", "r1", "--config", "station.toml", "--out", "OUT"], "--out")]


@pytest.mark.parametrize("k", range(17))
@pytest.mark.parametrize("there", ["/dev/full", "directory", "pipe", "under a file"])
def test_every_output_option_writes_only_over_a_regular_file(tmp_path, capsys, k, there):
    argv, option = _output_cases(tmp_path)[k]
    target, needle = _target(tmp_path, there)
    before = os.stat(target).st_mode if os.path.exists(target) else None
    _refused(capsys, [target if a == "OUT" else a for a in argv], f"{option} {target}", needle)
    if before is not None:
        assert os.stat(target).st_mode == before  # still the device, the directory, the pipe
    if Path(target).parent.is_dir():
        assert [p.name for p in Path(target).parent.iterdir() if p.name.endswith(".tmp")] == []


@pytest.mark.parametrize("k", range(len(_DIR_CASES)))
@pytest.mark.parametrize("there", ["/dev/full", "pipe", "under a file"])
def test_every_output_directory_is_a_directory(tmp_path, capsys, k, there):
    argv, option = _DIR_CASES[k]
    target, needle = _target(tmp_path, there)
    needle = {"pipe": "is a pipe, not a directory", "/dev/full": "is a character device, not a directory"}.get(
        there, needle)
    _refused(capsys, [target if a == "OUT" else a for a in argv], f"{option} {target}", needle)


def _target(tmp: Path, there: str) -> tuple[str, str]:
    if there == "/dev/full":
        return "/dev/full", "is a character device; only a regular file is replaced"
    if there == "directory":
        (tmp / "d").mkdir()
        return str(tmp / "d"), "is a directory; only a regular file is replaced"
    if there == "pipe":
        os.mkfifo(tmp / "f.fifo")
        return str(tmp / "f.fifo"), "is a pipe"
    (tmp / "plain").write_text("x")
    return str(tmp / "plain" / "out.json"), f"{tmp / 'plain'} is a regular file, not a directory"


def test_a_failed_write_leaves_the_old_file_and_no_temporary_file(tmp_path):
    f = tmp_path / "out.json"
    f.write_text("old")
    with pytest.raises(RuntimeError), output_file(f, "--json") as fh:
        fh.write("half")
        raise RuntimeError("stopped")
    assert f.read_text() == "old" and [p.name for p in tmp_path.iterdir()] == ["out.json"]
    g = tmp_path / "new.json"
    with output_file(g, "--json") as fh:
        fh.write("new")
    mask = os.umask(0o022)
    os.umask(mask)
    assert g.read_text() == "new" and stat.S_IMODE(os.stat(g).st_mode) == 0o666 & ~mask


# -- items 3 and 5: model files ----------------------------------------------------------------------------
def _good_model() -> dict:
    m = model_to_json(get_robot("industrial-3100").dh_nominal, name="m")
    m["effects"] = [{"effect": "backlash", "joint": 2, "params": {"b2_rad": 1e-4}},
                    {"effect": "thermal_drift", "params": {"dT_max_K": 4.0}, "tau_s": 3000.0}]
    return m


def _joints_csv(path: Path, rng, n: int = 6) -> Path:
    q = rng.uniform(-60, 60, (n, 6))
    rows = "".join(",".join(f"{v:.3f}" for v in r) + f",{10.0 * i},20,0" + ",1" * 6 + "\n" for i, r in enumerate(q))
    path.write_text("q1,q2,q3,q4,q5,q6,t,temperature,load,dir1,dir2,dir3,dir4,dir5,dir6\n" + rows)
    return path


_BASE = {"rotation_matrix": [[1, 0, 0], [0, 1, 0], [0, 0, 1]], "translation_mm": [0, 0, 0]}
MODEL_CASES = {
    "a_mm 1e200": (lambda m: m["joints"][1].update(a_mm=1e200), "joints[1].a_mm = 1e+200 mm is beyond"),
    "base t 1e308": (lambda m: m.update(base={**_BASE, "translation_mm": [1e308, 0, 0]}),
                     "base.translation_mm[0] = 1e+308 mm is beyond"),
    "alpha 1e300": (lambda m: m["effects"].__setitem__(1, {"effect": "thermal_drift", "params": {"alpha_per_K": 1e300}}),
                    "effects[1].params.alpha_per_K = 1e+300 1/K is beyond"),
    "negative tau": (lambda m: m["effects"][1].update(tau_s=-60.0), "effects[1].tau_s = -60.0 s is beyond"),
    "backlash 1e300": (lambda m: m["effects"][0]["params"].update(b2_rad=1e300), "effects[0].params.b2_rad"),
    "effect twice": (lambda m: m["effects"].append(copy.deepcopy(m["effects"][0])),
                     "effects[2]: backlash of joint 2 is listed twice"),
    "name a list": (lambda m: m.update(name=["a", "b"]), "'name' must be a text"),
    "1,500 effects": (lambda m: m.update(effects=[m["effects"][0]] * 1500), "lists 1500 effects; at most 19"),
    "ragged base": (lambda m: m.update(base={**_BASE, "rotation_matrix": [[1, 0, 0], [0, 1], [0, 0, 1]]}),
                    "base.rotation_matrix must be 3 lists of 3 numbers"),
    "string base": (lambda m: m.update(base={**_BASE, "rotation_matrix": "identity"}),
                    "base.rotation_matrix must be 3 lists of 3 numbers"),
    "50,000-digit tool": (lambda m: m["tool"].update(z_mm="BIG"), "tool.z_mm"),
    "compliance name": (lambda m: m["effects"].append({"effect": "joint_compliance", "joint": 3,
                                                       "params": {"c4_rad_per_Nm": 1e-6}}), "not c4_rad_per_Nm"),
}


@pytest.mark.parametrize("case", list(MODEL_CASES))
@pytest.mark.parametrize("command", ["predict", "compensate"])
def test_absurd_model_files_are_refused_naming_the_key(tmp_path, capsys, rng, case, command):
    change, needle = MODEL_CASES[case]
    m = _good_model()
    change(m)
    f = tmp_path / "m.json"
    f.write_text(json.dumps(m).replace('"BIG"', "9" * 50_000))
    out = tmp_path / "out.csv"
    if command == "predict":
        argv = ["predict", "arm", "--model", str(f), "--joints", str(_joints_csv(tmp_path / "q.csv", rng))]
    else:
        (tmp_path / "t.csv").write_text("x,y,z,t,temperature,load" + ",dir%d" * 6 % tuple(range(1, 7))
                                        + "\n1500,0,1200,0,20,0" + ",1" * 6 + "\n")
        argv = ["compensate", "arm", "--model", str(f), "--targets", str(tmp_path / "t.csv")]
    _refused(capsys, argv + ["--out", str(out)], f"{f}: ", needle)
    assert not out.exists()


@pytest.mark.parametrize("text, needle", [("[" * 200_000 + "]" * 200_000, "nested more than"),
                                          ('{"joints": ' + "9" * 50_000 + "}", "'joints' must be a list"),
                                          ("\xff\xfe", "not UTF-8"), ('{"joints": [', "not a JSON model")])
def test_malformed_model_json_is_refused(tmp_path, capsys, text, needle):
    f = tmp_path / "m.json"
    f.write_bytes(text.encode("latin-1") if text.startswith("\xff") else text.encode())
    _refused(capsys, ["predict", "arm", "--model", str(f), "--joints", "q.csv", "--out", str(tmp_path / "p.csv")],
             str(f), needle)


def test_a_huge_model_file_is_refused_before_it_is_parsed(tmp_path, capsys):
    f = tmp_path / "m.json"
    f.write_text('{"description": "' + "x" * MAX_MODEL_BYTES + '"}')
    tracemalloc.start()
    try:
        _refused(capsys, ["predict", "arm", "--model", str(f), "--joints", "q.csv", "--out", str(tmp_path / "p")],
                 f"{f}: larger than {MAX_MODEL_BYTES} bytes")
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 4 * MAX_MODEL_BYTES


def test_a_realistic_extended_model_is_read_and_predicts_near_its_table(tmp_path, rng):
    """No false alarm: the effects a realistic arm has pass the screen, and move the tool by less than a mm."""
    m = _good_model()
    m["effects"] += [{"effect": "encoder_eccentricity", "joint": 4, "params": {"s4_rad": 8e-5, "c4_rad": -3e-5}},
                     {"effect": "joint_compliance", "joint": 2, "params": {"k2_tcp_rad_per_kg": 1e-5}}]
    f = tmp_path / "m.json"
    f.write_text(json.dumps(m))
    arm = resolve_arm(str(f)).extended()
    q = np.radians(rng.uniform(-60, 60, (20, 6)))
    p = arm.predict(q, last_dir=np.ones((20, 6)), t_s=np.full(20, 600.0), load_kg=np.zeros(20))
    from station.models import kinematics as kin

    assert np.all(np.linalg.norm(p - kin.tool_position(arm.dh, q), axis=1) < 2.0)


UR_HEAD = "[mounting]\n"
UR_ZERO = {k: "[ 0, 0, 0, 0, 0, 0 ]" for k in ("delta_theta", "delta_a", "delta_d", "delta_alpha")}


def _ur_text(**changes) -> str:
    return UR_HEAD + "".join(f"{k} = {changes.get(k, v)}\n" for k, v in UR_ZERO.items())


@pytest.mark.parametrize("changes, needle", [
    ({"delta_theta": "[ 100, 0, 0, 0, 0, 0 ]"}, ":2: delta_theta[0] = 100 rad is beyond"),
    ({"delta_a": "[ 0, 1000, 0, 0, 0, 0 ]"}, ":3: delta_a[1] = 1000 m is beyond"),
    ({"delta_d": "[ True, 0, 0, 0, 0, 0 ]"}, ":4: delta_d[0] must be a number, got True"),
    ({"delta_d": "[ 'a', 0, 0, 0, 0, 0 ]"}, ":4: delta_d[0] must be a number, got 'a'"),
    ({"delta_alpha": "[ 0, 0, 0, 0, 0 ]"}, ":5: delta_alpha must be six numbers"),
    ({"delta_alpha": "[" * 1000 + "]" * 1000}, ":5: delta_alpha"),
    ({"delta_a": "[ " + "9" * 50_000 + ", 0, 0, 0, 0, 0 ]"}, ":3: longer than 4096"),
    ({"delta_a": "[ 1e999, 0, 0, 0, 0, 0 ]"}, ":3: delta_a[0] must be a finite number"),
])
def test_absurd_ur_calibration_files_are_refused_with_exit_2(tmp_path, capsys, changes, needle):
    f = tmp_path / "calibration.conf"
    f.write_text(_ur_text(**changes))
    _refused(capsys, ["calibrate", "arm", "--robot", "ur5e", "--ur-calibration", str(f), "--data",
                      str(tmp_path / "never-read.csv")], f"{f}{needle}")


# -- item 4: simulate ---------------------------------------------------------------------------------------
@pytest.mark.parametrize("argv, needle", [
    (["iso9283", "--cycles", "100000000"], "--cycles must be an integer within 1-100"),
    (["iso9283", "--dwell", "1e308"], "--dwell must be within 0-60 s"),
    (["iso9283", "--dwell", "1e6"], "--dwell must be within 0-60 s"),
    (["iso9283", "--wait", "1e9"], "--wait must be within 0-600 s"),
    (["iso9283", "--cycles", "100", "--dwell", "60", "--rate", "3000"], "at most 1,000,000 are simulated"),
    (["iso9283", "--seed", "-1"], "--seed must be an integer within 0-4294967295"),
    (["iso9283", "--beam-break", "1:1e300"], "--beam-break END must be within"),
    (["arm", "--poses", "100000000"], "--poses must be an integer within 10-20000"),
    (["arm", "--poses", "1" + "0" * 22], "--poses must be an integer within 10-20000"),
    (["arm", "--seed", "-1"], "--seed must be an integer"),
    (["trailer", "--duration", "1e7"], "--duration must be within 30-1800 s"),
    (["trailer", "--duration", "1e308"], "--duration must be within 30-1800 s"),
    (["trailer", "--seed", "4294967296"], "--seed must be an integer"),
    (["hold", "--duration", "1e7", "--rate", "3000"], "--duration must be within 3-14400 s"),
    (["hold", "--duration", "3600", "--rate", "3000"], "at most 1,000,000 are simulated"),
    (["hold", "--duration", "nan"], "--duration must be within"),
    (["hold", "--rate", "inf"], "--rate must be within 10-3000 Hz"),
])
def test_simulate_refuses_what_no_plant_asks_naming_the_option(tmp_path, capsys, argv, needle):
    out = tmp_path / "out"
    _refused(capsys, ["simulate", argv[0], "--out", str(out), *argv[1:]], needle)
    assert not out.exists()  # nothing written


def test_simulate_under_a_regular_file_is_refused(tmp_path, capsys):
    (tmp_path / "f").write_text("")
    _refused(capsys, ["simulate", "arm", "--out", str(tmp_path / "f" / "d")], "is a regular file, not a directory")


# -- item 5: the remaining tracebacks ------------------------------------------------------------------------
@pytest.mark.parametrize("value", ["1e308", "inf", "-1", "51"])
def test_analyze_temperature_uncertainty_is_bounded(tmp_path, capsys, value):
    (tmp_path / "s.csv").write_text(STOPS)
    _refused(capsys, ["analyze", "iso9283", "--stops", str(tmp_path / "s.csv"), "--decision-rule", "guarded",
                      "--temperature-u-k", value], "--temperature-u-k must be within 0-50 K")


@pytest.mark.parametrize("out, needle", [("dir", "is a directory"), ("file/x.toml", "is a regular file, not a"),
                                         ("/proc/x.toml", "cannot write there"), ("a" * 300 + ".toml", "a name of")])
def test_init_refuses_paths_it_cannot_write(tmp_path, capsys, monkeypatch, out, needle):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "dir").mkdir()
    (tmp_path / "file").write_text("")
    _refused(capsys, ["init", "--force", "--out", out], needle)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["dir", "file"]


# -- fuzz: model files, UR files, simulate options ------------------------------------------------------------
_DIR = Path(tempfile.mkdtemp(prefix="fuzz-hostile-"))  # one folder for the properties' many runs, removed at exit
atexit.register(shutil.rmtree, _DIR, True)
_ROBOT = get_robot("industrial-3100")
_Q = np.radians(np.random.default_rng(7).uniform(-90, 90, (8, 6)))
_ANY = st.recursive(st.none() | st.booleans() | st.integers(-10**40, 10**40) | st.floats(allow_nan=True)
                    | st.sampled_from([1e308, -1e300, 1e-320, 5e3, 0.05, 1e6]) | st.text(max_size=20),
                    lambda inner: st.lists(inner, max_size=4) | st.dictionaries(st.text(max_size=8), inner, max_size=4),
                    max_leaves=12)


def _paths(obj, prefix=()):
    yield prefix
    if isinstance(obj, dict):
        for k, v in obj.items():
            yield from _paths(v, prefix + (k,))
    elif isinstance(obj, list):
        for i, v in enumerate(obj):
            yield from _paths(v, prefix + (i,))


def _extended_model() -> dict:
    m = _good_model()
    m["base"] = copy.deepcopy(_BASE)
    m["joint_limits_deg"] = [[-170, 170]] * 6
    m["effects"] += [{"effect": "encoder_eccentricity", "joint": 4, "params": {"s4_rad": 8e-5, "c4_rad": -3e-5}},
                     {"effect": "joint_compliance", "joint": 2, "params": {"k2_tcp_rad_per_kg": 1e-5}}]
    return m


_MODEL_PATHS = list(_paths(_extended_model()))


@FUZZ
@given(edits=st.lists(st.tuples(st.sampled_from(_MODEL_PATHS), _ANY), min_size=1, max_size=3))
def test_fuzz_model_files_give_a_sane_arm_or_our_refusal(edits):
    m = _extended_model()
    for path, value in edits:
        if not path:
            m = value
            continue
        node = m
        try:
            for key in path[:-1]:
                node = node[key]
            node[path[-1]] = value
        except (KeyError, IndexError, TypeError):
            continue
    f = _DIR / "model.json"
    f.write_text(json.dumps(m))
    try:
        arm = resolve_arm(str(f)).extended()
        p = arm.predict(_Q, last_dir=np.ones_like(_Q), t_s=np.full(len(_Q), 900.0),
                        temperature_c=np.full(len(_Q), 25.0), load_kg=np.zeros(len(_Q)))
    except StationError:
        return
    # what is believed is an arm: tool points within its reach of the base, wherever the base is
    reach = np.abs(arm.dh[:, [0, 2]]).sum()
    base_t = np.zeros(3) if arm.base_T is None else arm.base_T[:3, 3]
    assert np.all(np.isfinite(p))
    assert np.all(np.linalg.norm(p - base_t, axis=1) < 1.01 * reach + 1.0)


_UR_VALUE = st.one_of(st.floats(allow_nan=True), st.integers(-10**30, 10**30), st.booleans(), st.text(max_size=5),
                      st.sampled_from([3.2, -3.2, 0.9, 1.1, 1e300]))


@FUZZ
@given(key=st.sampled_from(sorted(UR_ZERO)), values=st.lists(_UR_VALUE, min_size=0, max_size=8),
       junk=st.text(max_size=30))
def test_fuzz_ur_calibration_gives_a_sane_table_or_our_refusal(key, values, junk):
    f = _DIR / "calibration.conf"
    f.write_text(_ur_text(**{key: "[ " + ", ".join(repr(v) for v in values) + " ]"}) + junk + "\n")
    nominal = get_robot("ur5e").dh_nominal
    try:
        dh = read_ur_calibration(f, nominal)
    except StationError:
        return
    d = dh - nominal
    assert np.all(np.isfinite(dh))
    assert np.all(np.abs(d[:6, [1, 3]]) <= math.pi) and np.all(np.abs(d[:6, [0, 2]]) <= 1000.0)


_SIM_OPTIONS = {
    "iso9283": {"--cycles": ("int", 1, 100), "--dwell": ("real", 0, 60), "--rate": ("real", 10, 3000),
                "--seed": ("int", 0, 2**32 - 1), "--wait": ("real", 0, 600)},
    "arm": {"--poses": ("int", 10, 20_000), "--seed": ("int", 0, 2**32 - 1)},
    "trailer": {"--duration": ("real", 30, 1800), "--seed": ("int", 0, 2**32 - 1)},
    "hold": {"--duration": ("real", 3, 14_400), "--rate": ("real", 10, 3000), "--seed": ("int", 0, 2**32 - 1)},
}
_SIM_CASES = [(cmd, opt) for cmd, opts in _SIM_OPTIONS.items() for opt in opts]


def _beyond(kind, lo, hi):
    huge = st.sampled_from(["1e308", "1e22", "inf", "-inf", "nan", "1" + "0" * 400])
    if kind == "int":
        return st.one_of(st.integers(hi + 1, 10**30).map(str), st.integers(-10**30, lo - 1).map(str), huge)
    return st.one_of(st.floats(hi * 1.0001, 1e308).map(repr), st.floats(-1e308, lo - 1e-3).map(repr), huge)


@FUZZ
@given(data=st.data())
def test_fuzz_every_simulate_option_beyond_its_range_is_refused_by_name(data):
    cmd, opt = data.draw(st.sampled_from(_SIM_CASES))
    kind, lo, hi = _SIM_OPTIONS[cmd][opt]
    value = data.draw(_beyond(kind, lo, hi))
    out = _DIR / "sim-out"
    import contextlib
    import io

    err = io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
        try:
            code = main(["simulate", cmd, "--out", str(out), opt, value])
        except SystemExit as exc:  # argparse: not an integer at all
            code = exc.code
    assert code == 2, (cmd, opt, value, err.getvalue())
    assert "Traceback" not in err.getvalue()
    assert opt in err.getvalue(), err.getvalue()
    assert not out.exists()



@FUZZ
@given(cmd=st.sampled_from(["iso9283", "arm"]),
       robot=st.text(min_size=1, max_size=30).filter(lambda t: not t.startswith("-") and "\x00" not in t))
def test_fuzz_simulate_robot_names_are_a_library_robot_or_refused(cmd, robot):
    import contextlib
    import io

    from station.models.robots import ROBOT_NAMES

    if robot in ROBOT_NAMES:
        return
    err = io.StringIO()
    out = _DIR / "sim-robot"
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
        code = main(["simulate", cmd, "--out", str(out), "--robot", robot])
    assert code == 2 and "unknown robot" in err.getvalue() and "Traceback" not in err.getvalue(), err.getvalue()
    assert not out.exists()
