"""Date-time stamps as lab software writes them, to seconds from the first stamp.

Forms read (a stamp is a date, a space or ``T``, and a time of day):

* dates: ISO ``YYYY-MM-DD`` or ``YYYY/MM/DD``; ``A/B/YY`` or ``A/B/YYYY``, whose day and
  month order the form does not say (``MM/DD`` in US exports, ``DD/MM`` elsewhere);
  ``DD.MM.YYYY`` or ``DD.MM.YY`` (day first); ``DD-MM-YYYY``;
* times: ``HH:MM:SS`` with or without a fraction of a second, 24 h, or 12 h with
  ``AM``/``PM``; a trailing ``Z`` is accepted (the stamps are all in one zone);
  ``23:59:60`` (a UTC leap second) is the 61st second of its minute, and the
  stamps after it count it.

Two-digit years are 2000-2068 / 1969-1999 as C's ``strptime`` reads them.

Day and month order of ``A/B/Y`` stamps: a field above 12 settles it. When
nothing settles it, the order cannot matter for the intervals while every
stamp carries the same date (or the dates under either order lie the same
number of days apart): the stamps are read without asking. Otherwise (a run
over midnight whose date changes) :func:`stamps_to_seconds` refuses with the
reason and names the option that settles it (``--date-order``).
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from datetime import date

from station.errors import DataError

#: the orders the option ``--date-order`` takes for ``A/B/Y`` dates
DATE_ORDERS = ("mdy", "dmy")

_TIME = r"(?P<H>\d{1,2}):(?P<M>\d{2}):(?P<S>\d{2}(?:\.\d*)?)\s*(?P<ampm>[AaPp][Mm])?\s*Z?"
_FORMS = (
    ("ymd", re.compile(r"^(?P<a>\d{4})[-/](?P<b>\d{1,2})[-/](?P<c>\d{1,2})(?:\s+|T)" + _TIME + "$")),
    ("slash", re.compile(r"^(?P<a>\d{1,2})/(?P<b>\d{1,2})/(?P<c>\d{2}|\d{4})\s+" + _TIME + "$")),
    ("dmy", re.compile(r"^(?P<a>\d{1,2})[.-](?P<b>\d{1,2})[.-](?P<c>\d{2}|\d{4})\s+" + _TIME + "$")),
)
FORM_TEXT = ("YYYY-MM-DD, MM/DD/YY(YY) or DD/MM/YY(YY), DD.MM.YYYY, then HH:MM:SS[.fff] (24 h) "
             "or hh:MM:SS[.fff] AM/PM")


@dataclass(frozen=True)
class Stamp:
    """One stamp split: the date fields as written (``a``, ``b``, ``year``), its form, and the time of day in s."""

    form: str
    a: int
    b: int
    year: int
    day_s: float
    #: the 61st second of a minute (``23:59:60``): a leap second
    leap: bool = False


def _year(text: str) -> int:
    y = int(text)
    if len(text) == 2:
        y += 2000 if y < 69 else 1900
    return y


def parse_stamp(text: str) -> Stamp | None:
    """The stamp's fields, or None when it is none of the forms read (the time of day checked here)."""
    s = " ".join(text.split())
    for form, rx in _FORMS:
        m = rx.match(s)
        if m is None:
            continue
        h, mi, sec = int(m["H"]), int(m["M"]), float(m["S"])
        if m["ampm"]:
            if not 1 <= h <= 12:
                return None
            h = h % 12 + (12 if m["ampm"].lower() == "pm" else 0)
        if h > 23 or mi > 59 or sec >= 61.0:
            return None
        day_s, leap = h * 3600.0 + mi * 60.0 + sec, sec >= 60.0
        if form == "ymd":
            return Stamp("ymd", int(m["b"]), int(m["c"]), int(m["a"]), day_s, leap)
        return Stamp(form, int(m["a"]), int(m["b"]), _year(m["c"]), day_s, leap)
    return None


def _day(year: int, month: int, day: int) -> int | None:
    try:
        return date(year, month, day).toordinal()
    except ValueError:
        return None


def _days(dates, order: str) -> list[int | None]:
    """Day numbers of the distinct ``(form, a, b, year)`` dates read in ``order`` (``mdy``/``dmy``)."""
    out = []
    for form, a, b, y in dates:
        if form == "ymd":
            out.append(_day(y, a, b))
        elif form == "dmy" or order == "dmy":
            out.append(_day(y, b, a))
        else:
            out.append(_day(y, a, b))
    return out


@dataclass(frozen=True)
class DateReading:
    """Seconds from the first stamp and how the dates were read (``order``: ``mdy``, ``dmy`` or None when no
    ``A/B/Y`` stamp is there; ``settled_by``: ``field>12``, ``option``, ``one date`` or ``either``)."""

    t_s: list[float]
    order: str | None
    settled_by: str | None
    #: indices of the stamps after which a leap second was counted (the first stamp past each ``:60``)
    leap_rows: tuple[int, ...] = ()


def stamps_to_seconds(stamps: list[Stamp], *, date_order: str | None = None, where=None) -> DateReading:
    """Seconds from the first stamp; ``where(i)`` names row ``i`` in messages (file and line).

    Raises DataError when the forms are mixed, a date does not exist, or the
    day/month order of ``A/B/Y`` dates is not settled and changes the intervals.
    """
    where = where or (lambda i: f"row {i + 1}")
    if date_order is not None and date_order not in DATE_ORDERS:
        raise DataError(f"--date-order must be one of {', '.join(DATE_ORDERS)}, got {date_order!r}")
    if not stamps:
        return DateReading([], None, None)
    forms = {s.form for s in stamps}
    if len(forms) > 1:
        i = next(k for k, s in enumerate(stamps) if s.form != stamps[0].form)
        raise DataError(f"{where(i)}: the date is written in another form than on the first row")
    keys = sorted({(s.form, s.a, s.b, s.year) for s in stamps})
    order, settled = None, None
    if stamps[0].form == "slash":
        first_big = [k for k in keys if k[1] > 12]
        second_big = [k for k in keys if k[2] > 12]
        if first_big and second_big:
            i = next(k for k, s in enumerate(stamps) if s.b > 12)
            raise DataError(f"{where(i)}: a date field above 12 in both the first and the second place of the "
                            "dates (some stamps day first, others month first?)")
        if date_order is not None:
            order, settled = date_order, "option"
            if (order == "mdy" and first_big) or (order == "dmy" and second_big):
                i = next(k for k, s in enumerate(stamps) if (s.a if order == "mdy" else s.b) > 12)
                raise DataError(f"{where(i)}: --date-order {order} reads a month above 12 here")
        elif first_big or second_big:
            order, settled = ("dmy" if first_big else "mdy"), "field>12"
        elif len(keys) == 1:
            order, settled = "mdy", "one date"
        else:
            d_m, d_d = _days(keys, "mdy"), _days(keys, "dmy")
            if None not in d_m and None not in d_d and \
                    [x - d_m[0] for x in d_m] == [x - d_d[0] for x in d_d]:
                order, settled = "mdy", "either"
            else:
                first = stamps[0]
                i = next(k for k, s in enumerate(stamps) if (s.a, s.b, s.year) != (first.a, first.b, first.year))
                raise DataError(
                    f"{where(i)}: the date changes from {first.a:02d}/{first.b:02d} to {stamps[i].a:02d}/"
                    f"{stamps[i].b:02d} and nothing in the file says whether dates are month/day or day/month; "
                    "the intervals across the change differ between the two: give --date-order mdy or "
                    "--date-order dmy")
    days = dict(zip(keys, _days(keys, order or "mdy")))
    for k, d in days.items():
        if d is None:
            i = next(j for j, s in enumerate(stamps) if (s.form, s.a, s.b, s.year) == k)
            raise DataError(f"{where(i)}: the date {k[1]}/{k[2]}/{k[3]} does not exist"
                            + (f" read as {order}" if order else ""))
    d0 = days[(stamps[0].form, stamps[0].a, stamps[0].b, stamps[0].year)]
    s0 = stamps[0].day_s
    t = [(days[(s.form, s.a, s.b, s.year)] - d0) * 86400.0 + (s.day_s - s0) for s in stamps]
    leap_rows = _count_leap_seconds(stamps, t) if any(s.leap for s in stamps) else ()
    return DateReading(t, order, settled, leap_rows)


def _count_leap_seconds(stamps: list[Stamp], t: list[float]) -> tuple[int, ...]:
    """Add the leap second to every stamp after a ``:60`` second (in place); the first row after each.

    ``23:59:60.5`` read as seconds of the day is ``00:00:00.5`` of the next:
    the stamps after the leap second would go back (or repeat, in whole
    seconds). A ``:60`` stamp followed by one that reads no later is a leap
    second: one second more is counted from there on. A ``:60`` stamp followed
    by later ones (a logger that rounds ``59.9996`` up) is left as it reads.
    """
    rows = []
    offset = 0.0
    for i in range(len(stamps)):
        t[i] += offset
        if stamps[i].leap and i + 1 < len(stamps) and not stamps[i + 1].leap and t[i + 1] + offset <= t[i]:
            offset += 1.0
            rows.append(i + 1)
    return tuple(rows)
