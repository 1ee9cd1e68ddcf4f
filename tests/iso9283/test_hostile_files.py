"""Hostile files (issue reproducers): each a clean refusal naming file and line, exit 2, no traceback."""

from __future__ import annotations

import pytest

from app.cli import main

ROWS = "\n".join(f"{i * 0.01:.2f},{i},{i},{i}" for i in range(2000))


def _stream_cases():
    return {
        "bigcell": ("t,x,y,z,status\n" + "\n".join(
            f"{i * 0.01:.2f},{i},{i},{i},{'0' if i else 'x' * 100_000}" for i in range(2000)) + "\n", "line 2"),
        "wide": ("t,x,y,z" + "," * 100_000 + "\n" + ROWS + "\n", "line 1"),
        "nonutf": (("t,x,y,z\n" + ROWS + "\n").encode()[:9000] + b"\xff\n1,2,3,4\n", "not UTF-8"),
        "longfield": ("t,x,y,z\n1," + "9" * 140_000 + ",2,3\n" + ROWS + "\n", "line 2"),
    }


@pytest.mark.parametrize("name", list(_stream_cases()))
def test_hostile_stream_files_are_refused_cleanly(tmp_path, capsys, name):
    data, match = _stream_cases()[name]
    f = tmp_path / f"{name}.csv"
    f.write_bytes(data if isinstance(data, bytes) else data.encode())
    poses = tmp_path / "p.csv"
    poses.write_text("name,x,y,z\nP1,1,2,3\n")
    assert main(["analyze", "iso9283", "--stream", str(f), "--poses", str(poses)]) == 2
    err = capsys.readouterr().err
    assert "Traceback" not in err and err.startswith("station: error:") and match in err and f.name in err


def test_a_header_with_spaces_names_its_columns(tmp_path, capsys):
    """'t,x,y, z' gave an ArrowKeyError traceback: the stripped names are the columns."""
    f = tmp_path / "s.csv"
    f.write_text("t,x,y, z\n" + ROWS + "\n")
    poses = tmp_path / "p.csv"
    poses.write_text("name,x,y,z\nP1,1,2,3\n")
    code = main(["analyze", "iso9283", "--stream", str(f), "--poses", str(poses)])
    err = capsys.readouterr().err
    assert "Traceback" not in err and code != 2  # read: whatever the verdict, not a refusal of the file


@pytest.mark.parametrize("content, match", [
    (b"t,kappa,psi\n0,0.1,0.2\n\xff,0.1,0.2\n", "line 3, byte 1: not UTF-8"),
    ("t,kappa,psi\n" + "\n".join(f"{i * 0.05:.2f},0.1,0.2,9,9" for i in range(50)) + "\n", "5 fields, the header has 3"),
    ("t,kappa,psi\n0," + "1" * 140_000 + ",0.2\n", "line 2: longer than 4096 characters"),
])
def test_hostile_trailer_files_are_refused_cleanly(tmp_path, capsys, content, match):
    f = tmp_path / "T.csv"
    f.write_bytes(content if isinstance(content, bytes) else content.encode())
    assert main(["calibrate", "trailer", "--data", str(f)]) == 2
    err = capsys.readouterr().err
    assert "Traceback" not in err and match in err
