"""What the hostile-input tests hold a refusal to: exit 2, one ``station: error:`` line naming the input, no traceback."""

from __future__ import annotations

from app.cli import main


def refused(capsys, argv, *needles) -> str:
    """``main(argv)`` exits 2 with a one-line error holding every needle, no traceback; the error text."""
    code = main(argv)
    err = capsys.readouterr().err
    assert code == 2, err
    assert err.startswith("station: error:") and "Traceback" not in err, err
    for n in needles:
        assert n in err, (n, err)
    assert max(len(w) for w in err.split()) < 400  # no 309-digit numbers, no 100,000-character cells
    return err
