"""The ISO 9283 characteristics, declared once, as data.

One :class:`Characteristic` per figure: its key (the unit in the name,
``AP_mm``), its unit, the level it is stated at, the key of its limit in a
station config, a title, and the function that reads it off its subject's
result (the formula itself is in :mod:`station.analysis.iso9283.characteristics`,
cited by seed equation number in the title).  Everything that names
characteristics is made from this table:

* the limits a station config accepts (``robots.<r>.limits.<limit_key>``,
  :mod:`station.config`) and the keys ``station analyze iso9283 --limit``
  accepts (:func:`limit_levels`, :func:`check_limits` of the analysis);
* the verdicts of an analysis (every limited characteristic, every subject of
  its level, in the table's order);
* the rows the ISO 9283 procedure stores (and so the store's history, the
  operator page's history names, the console's columns and the report's
  figures) and the units of the JSON and of the uncertainty.

Adding a characteristic is one row below (and its formula). A row can also be
added for the length of a ``with`` block (:func:`added`), as the tests do.

Levels: ``pose`` (one figure per commanded pose, subject ``"P1"``), ``pair``
(a pose pair, ``"P2-P4"``), ``move`` (a move between two poses,
``"P1->P2"``), ``path`` (a path segment, ``"P1->P2"``), ``direction`` (a load
direction of the static compliance test, ``"+x"``), ``run`` (one figure for
the whole run, subject ``"run"``).

Programmes: each row says which test states it. ``pose`` is the ISO 9283
pose test (``station run iso9283``, ``station analyze iso9283``; it also
states AT/RT of straight moves in its stream), ``path`` the path test's
analysis (``station analyze path``, clauses 8.2-8.5 and 11), ``compliance``
the static compliance test (clause 10), ``fleet`` the figures over several
robots' stored runs (exchangeability, 7.8), ``drift`` the drift programme
(``station run iso9283-drift``: the pose test repeated over hours from a cold
start, :mod:`station.analysis.iso9283.drift_programme`). The functions below answer for
the pose test unless a programme is named.
"""

from __future__ import annotations

import contextlib
import math
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import Any

#: the levels a characteristic is stated at, in the order the verdicts and rows list them
LEVELS = ("pose", "pair", "move", "path", "direction", "run")

#: the tests that state characteristics (see the module's docstring)
PROGRAMMES = ("pose", "path", "compliance", "fleet", "drift")


@dataclass(frozen=True)
class Characteristic:
    """One ISO 9283 characteristic.

    ``figure(subject)`` reads the value off the result of one subject of the
    level (a pose's ``PoseResult``, a pair's ``DistanceAR``, a move's
    ``PosingTime``, a path's ``PathAR``, the run's whole result); None when it
    could not be computed, and ``missing`` (a sentence, or a function of the
    subject giving one) says why.
    """

    key: str
    unit: str
    level: str
    #: the key of its limit in a station config (``ap_limit_mm``); None: stated, never judged
    limit_key: str | None
    title: str
    figure: Callable[[Any], float | None]
    missing: str | Callable[[Any], str] = "not computed"
    #: a row of every ISO 9283 procedure run, limited or not (else a row only where a limit is configured)
    stated: bool = False
    #: judged on the multi-directional cycles (eq. (7)); else on the single-direction pose cycles
    several_approaches: bool = False
    #: computed from the motion between stops: a stop list cannot give it
    needs_stream: bool = False
    #: a figure of the run's report (the values of its subjects against the limit)
    plotted: bool = False
    #: a key of its subject's JSON (orientation and drift figures are keys of their own blocks there)
    in_json: bool = True
    #: the equation of seed 000 (or the ISO 9283 clause) it implements
    source: str = ""
    #: the test that states it (:data:`PROGRAMMES`)
    programme: str = "pose"
    #: a row of every run whose data carry the tool's orientation (a 6-DoF tracker), limited or not
    with_orientation: bool = False

    def __post_init__(self) -> None:
        if self.level not in LEVELS:
            raise ValueError(f"characteristic {self.key}: level {self.level!r} is not one of {', '.join(LEVELS)}")
        if self.programme not in PROGRAMMES:
            raise ValueError(f"characteristic {self.key}: programme {self.programme!r} is not one of "
                             f"{', '.join(PROGRAMMES)}")
        suffix = unit_suffix(self.unit)
        if self.unit != "1" and not self.key.endswith(f"_{suffix}"):
            raise ValueError(f"characteristic {self.key}: the key must carry its unit ({self.unit})")
        if self.limit_key is not None and not self.limit_key.endswith(f"_{suffix}"):
            raise ValueError(f"characteristic {self.key}: limit key {self.limit_key} must carry the unit {self.unit}")

    @property
    def symbol(self) -> str:
        """The key without its unit (``AP``)."""
        return self.key if self.unit == "1" else self.key[: -len(unit_suffix(self.unit)) - 1]

    @property
    def column(self) -> str:
        """Console column header: ``AP mm`` (``n`` for a count)."""
        return "n" if self.unit == "1" else f"{self.symbol} {self.unit}"

    def why_missing(self, subject) -> str:
        return self.missing(subject) if callable(self.missing) else self.missing

    def value(self, subject) -> float | None:
        """The figure as a float, None where it is not computed (or not finite)."""
        v = self.figure(subject)
        if v is None:
            return None
        v = float(v)
        return v if math.isfinite(v) else None


def unit_suffix(unit: str) -> str:
    """How a unit is spelled at the end of a key: ``mm``, ``s``, ``percent`` for %, ``mm_per_N`` for mm/N."""
    return unit.replace("%", "percent").replace("/", "_per_")


def _pose(attr: str, field: str):
    def get(pr):
        part = getattr(pr, attr)
        return None if part is None else getattr(part, field)
    return get


def _angle(kind: str, j: int):
    def get(pr):
        o = pr.orientation
        a = None if o is None else getattr(o, f"{kind}_rad")
        return None if a is None else math.degrees(float(a[j]))
    return get


def _angle_vap(j: int):
    def get(pr):
        v = pr.multidirectional.vAP_rad
        return None if v is None else math.degrees(float(v[j]))
    return get


_BAND = "no limit band or no complete approach"
_DRIFT = "too few cycles for two drift blocks"

_ROWS: tuple[Characteristic, ...] = (
    Characteristic("AP_mm", "mm", "pose", "ap_limit_mm", "Position accuracy AP", _pose("accuracy", "AP_mm"),
                   "no attained pose", stated=True, plotted=True, source="eq. (1)"),
    Characteristic("RP_mm", "mm", "pose", "rp_limit_mm", "Position repeatability RP",
                   _pose("repeatability", "RP_mm"), "fewer than 2 attained poses", stated=True, plotted=True,
                   source="eq. (2)"),
    Characteristic("POS_mm", "mm", "pose", "pos_limit_mm", "Position overshoot POS", _pose("overshoot", "POS_mm"),
                   _BAND, stated=True, needs_stream=True, source="eq. (5)"),
    Characteristic("PST_s", "s", "pose", "pst_limit_s", "Position stabilisation time PST",
                   _pose("overshoot", "PST_s"), _BAND, stated=True, needs_stream=True, source="eq. (6)"),
    Characteristic("vAP_mm", "mm", "pose", "vap_limit_mm", "Multi-directional position accuracy variation vAP",
                   lambda pr: pr.multidirectional.vAP_mm,
                   lambda pr: f"{pr.multidirectional.n_directions} approach direction(s), 3 needed",
                   stated=True, several_approaches=True, source="eq. (7)"),
    Characteristic("dAP_mm", "mm", "pose", "dap_limit_mm", "Drift of position accuracy dAP", _pose("drift", "dAP_mm"),
                   _DRIFT, needs_stream=True, in_json=False, source="ISO 9283 drift"),
    Characteristic("dRP_mm", "mm", "pose", "drp_limit_mm", "Drift of position repeatability dRP",
                   _pose("drift", "dRP_mm"), _DRIFT, needs_stream=True, in_json=False, source="ISO 9283 drift"),
    *(Characteristic(f"{kind}{ax}_deg", "deg", "pose", f"{kind.lower()}{ax}_limit_deg",
                     f"Orientation {'accuracy' if kind == 'AP' else 'repeatability'} {kind}{ax}",
                     _angle(kind, j), "no orientation data", needs_stream=kind == "AP", in_json=False,
                     source="ISO 9283 orientation (seed 000 sec. 3.1; eqs. (1)-(2) per angle)",
                     with_orientation=True)
      for j, ax in enumerate("abc") for kind in ("AP", "RP")),
    *(Characteristic(f"vAP{ax}_deg", "deg", "pose", f"vap{ax}_limit_deg",
                     f"Multi-directional orientation accuracy variation vAP{ax}", _angle_vap(j),
                     "no orientation data or fewer than 3 approach directions", several_approaches=True,
                     in_json=False, source="ISO 9283 7.2.2 orientation (eq. (7) per angle: max - min of the "
                                           "directions' mean angles)", with_orientation=True)
      for j, ax in enumerate("abc")),
    Characteristic("n_cycles", "1", "pose", None, "Attained cycles", lambda pr: pr.n_cycles, stated=True),
    Characteristic("AD_mm", "mm", "pair", "ad_limit_mm", "Distance accuracy AD", lambda d: d.AD_mm,
                   "fewer than 2 cycles", stated=True, source="eq. (8)"),
    Characteristic("RD_mm", "mm", "pair", "rd_limit_mm", "Distance repeatability RD", lambda d: d.RD_mm,
                   "fewer than 2 cycles", stated=True, source="eq. (9)"),
    Characteristic("MPT_s", "s", "move", "mpt_limit_s", "Minimum posing time", lambda m: m.MPT_s,
                   "fewer posing times than repeats", stated=True, needs_stream=True, plotted=True, source="eq. (10)"),
    Characteristic("AT_mm", "mm", "path", "at_limit_mm", "Path accuracy AT", lambda p: p.AT_mm,
                   "fewer than 2 traversals", needs_stream=True, source="ISO 9283 path accuracy"),
    Characteristic("RT_mm", "mm", "path", "rt_limit_mm", "Path repeatability RT", lambda p: p.RT_mm,
                   "fewer than 2 traversals", needs_stream=True, source="ISO 9283 path repeatability"),
    # the path test (station.analysis.path): one value per commanded path of the path file
    *(Characteristic(key, unit, "path", None, title, lambda p, key=key: getattr(p, key, None), "not stated for this path",
                     needs_stream=True, source=f"ISO 9283 {clause}", programme="path")
      for key, unit, clause, title in (
          ("AT_mm", "mm", "8.2", "Path accuracy AT: largest distance of a normal plane's barycentre from the commanded point"),
          ("RT_mm", "mm", "8.2", "Path repeatability RT: largest l_bar + 3 S_l over the normal planes"),
          ("CR_mm", "mm", "8.4", "Cornering round-off error CR: least distance of the attained path from the corner "
                                 "point (largest over corners and cycles)"),
          ("CO_mm", "mm", "8.4", "Cornering overshoot CO: largest deviation outward of the second edge after the "
                                 "corner (largest over corners and cycles)"),
          ("AV_percent", "%", "8.5", "Path velocity accuracy AV: (mean attained speed - commanded) / commanded"),
          ("RV_percent", "%", "8.5", "Path velocity repeatability RV: 3 S of the cycles' mean speeds / commanded"),
          ("FV_percent", "%", "8.5", "Path velocity fluctuation FV: largest max - min of the speed within one cycle "
                                     "/ commanded"),
          ("WS_percent", "%", "11", "Weaving stroke error WS: (mean attained amplitude - commanded) / commanded"),
          ("WF_percent", "%", "11", "Weaving frequency error WF: (mean attained frequency - commanded) / commanded"),
      )),
    # the static compliance test (station.analysis.iso9283.compliance): one value per load direction
    Characteristic("compliance_mm_per_N", "mm/N", "direction", None, "Static compliance",
                   lambda d: getattr(d, "compliance_mm_per_N", None), "no loading in this direction", stated=True,
                   source="ISO 9283 clause 10: slope of the displacement along the load against the load",
                   programme="compliance"),
    # over several robots of one model (station.fleet.exchangeability): one value per pose and the largest
    Characteristic("exchangeability_mm", "mm", "pose", None, "Exchangeability",
                   lambda e: getattr(e, "exchangeability_mm", None), "fewer than 2 robots",
                   source="ISO 9283 7.8: largest distance between the barycentres of the robots at a pose",
                   programme="fleet"),
    # the drift programme (station.analysis.iso9283.drift_programme): one value per pose, first visit against
    # last; the same config limits as the pose test's drift over blocks of cycles
    Characteristic("dAP_mm", "mm", "pose", "dap_limit_mm", "Drift of position accuracy dAP over the programme",
                   lambda d: getattr(d, "dAP_mm", None), "attained at fewer than two visits", stated=True,
                   source="ISO 9283 drift: |AP(t_1) - AP(t_n)|, AP by eq. (1)", programme="drift"),
    Characteristic("dRP_mm", "mm", "pose", "drp_limit_mm", "Drift of position repeatability dRP over the programme",
                   lambda d: getattr(d, "dRP_mm", None), "fewer than two stops at the first or last visit",
                   stated=True, source="ISO 9283 drift: |RP(t_1) - RP(t_n)|, RP by eq. (2)", programme="drift"),
    # with a 6-DoF target, the orientation's per angle, judged against the robot's d<kind><axis>_limit_deg
    *(Characteristic(f"d{kind}{ax}_deg", "deg", "pose", f"d{kind.lower()}{ax}_limit_deg",
                     f"Drift of orientation {'accuracy' if kind == 'AP' else 'repeatability'} d{kind}{ax} over the "
                     "programme", lambda d, k=f"d{kind}{ax}_deg": (getattr(d, "orientation", None) or {}).get(k),
                     "no orientation at the first or last visit (a 6-DoF target)",
                     source=f"ISO 9283 drift: |{kind}{ax}(t_1) - {kind}{ax}(t_n)|, {kind}{ax} per angle "
                            "(seed 000 sec. 3.1)", programme="drift", with_orientation=True)
      for kind in ("AP", "RP") for ax in "abc"),
)


def _check_unique(rows) -> None:
    for attr in ("key", "limit_key"):
        seen = [(c.programme, getattr(c, attr)) for c in rows if getattr(c, attr) is not None]
        twice = sorted({k for k in seen if seen.count(k) > 1})
        if twice:
            raise ValueError(f"the characteristics table names {attr} {', '.join(k for _, k in twice)} twice")


_check_unique(_ROWS)


#: (programme, id of the table) -> (the table, its rows of the programme): the JSON asks once per pose
_BY_PROGRAMME: dict[tuple[str, int], tuple[tuple, tuple]] = {}


def characteristics(programme: str = "pose") -> tuple[Characteristic, ...]:
    """The characteristics ``programme`` states, in the table's order (the order of verdicts and rows within
    a level); ``"*"``: every row."""
    hit = _BY_PROGRAMME.get((programme, id(_ROWS)))
    if hit is not None and hit[0] is _ROWS:  # the same table (:func:`added` makes a new one)
        return hit[1]
    out = _ROWS if programme == "*" else tuple(c for c in _ROWS if c.programme == programme)
    if len(_BY_PROGRAMME) > 64:  # tables of :func:`added` that are gone
        _BY_PROGRAMME.clear()
    _BY_PROGRAMME[(programme, id(_ROWS))] = (_ROWS, out)
    return out


def get(key: str, programme: str = "pose") -> Characteristic | None:
    """The characteristic of ``key`` (``"AP_mm"``) that ``programme`` states, None when the table has none."""
    return next((c for c in characteristics(programme) if c.key == key), None)


def limit_levels(programme: str = "pose") -> dict[str, str]:
    """``{key: level}`` of every characteristic a limit can be given for (``--limit KEY=VALUE``)."""
    return {c.key: c.level for c in characteristics(programme) if c.limit_key is not None}


def config_limit_keys(programme: str = "pose") -> dict[str, str]:
    """``{config limit key: characteristic key}`` (``{"ap_limit_mm": "AP_mm", ...}``) of ``programme``."""
    return {c.limit_key: c.key for c in characteristics(programme) if c.limit_key is not None}


#: the programmes whose limits are a robot's (``robots.<r>.limits`` of a station config); the path test's are
#: its own section's (``path_limits``)
ROBOT_LIMIT_PROGRAMMES = ("pose", "drift")


def robot_limit_keys() -> dict[str, str]:
    """``{config limit key: characteristic key}`` a robot's limits may hold: the pose test's and the drift
    programme's (``dap_limit_mm`` is both's dAP)."""
    out: dict[str, str] = {}
    for programme in ROBOT_LIMIT_PROGRAMMES:
        out.update(config_limit_keys(programme))
    return out


def unit_of(key: str) -> str:
    """The unit of a characteristic (from the table, any programme; the key's suffix for a name it lacks)."""
    c = get(key) or get(key, "*")
    return c.unit if c is not None else key.rsplit("_", 1)[-1]


def history_names() -> tuple[str, ...]:
    """The figures every run states, to follow across a robot's runs (counts left out): the pose test's, the
    path test's (every figure of each of its paths, :func:`procedures.iso9283_path.rows_of`), the compliance
    test's and the drift programme's (each key once), and the orientation figures a run with a 6-DoF target
    states (a robot measured with positions only has no values of them, and its page skips them)."""
    keys = [c.key for c in _ROWS if c.unit != "1" and (c.programme == "path" or (
        (c.stated or c.with_orientation) and c.programme in ("pose", "compliance", "drift")))]
    return tuple(dict.fromkeys(keys))


def has_orientation(result) -> bool:
    """Whether an analysis result states the tool's orientation at some pose (its data were 6-DoF)."""
    return any(getattr(pr, "orientation", None) is not None for pr in getattr(result, "poses", {}).values())


def subjects(result, level: str) -> list[tuple[str, Any]]:
    """``[(subject name, its result)]`` of ``level`` in an analysis result (stream or stop list)."""
    if level == "pose":
        return list(result.poses.items())
    if level == "pair":
        return [(f"{d.pose_a}-{d.pose_b}", d) for d in getattr(result, "distances", ())]
    if level == "move":
        return [(f"{m.from_pose}->{m.to_pose}", m) for m in getattr(result, "posing_times", ())]
    if level == "path":
        return [(f"{p.from_pose}->{p.to_pose}", p) for p in getattr(result, "paths", ())]
    return [("run", result)]


def figures(result, select: Callable[[Characteristic], bool] = lambda c: True
            ) -> Iterator[tuple[Characteristic, str, Any]]:
    """``(characteristic, subject name, subject result)`` of ``result`` for the selected characteristics:
    level by level, subject by subject, in the table's order."""
    for level in LEVELS:
        chars = [c for c in characteristics() if c.level == level and select(c)]
        if not chars:
            continue
        for name, subject in subjects(result, level):
            for c in chars:
                yield c, name, subject


def from_their_cycles(one, several, key: Callable[[Any], str] = lambda v: v.characteristic) -> list:
    """What a run analysed twice states (verdicts, their JSON, uncertainties): from ``one``, the analysis of
    the single-direction pose cycles, every characteristic but those of several approaches, which come from
    ``several``, the analysis of the multi-directional cycles (seed 000 Table 3). ``key``: an item's
    characteristic."""
    def multi(item) -> bool:
        c = get(key(item))
        return c is not None and c.several_approaches

    return [x for x in one if not multi(x)] + [x for x in several if multi(x)]


@contextlib.contextmanager
def added(*rows: Characteristic) -> Iterator[None]:
    """The table with ``rows`` appended, for the length of the block (a new characteristic tried out)."""
    global _ROWS
    before = _ROWS
    _check_unique(before + rows)
    _ROWS = before + rows
    try:
        yield
    finally:
        _ROWS = before
