"""One self-contained HTML report per run: numbers, verdicts, plots.

Plots are drawn with matplotlib (Agg) into inline SVG, so the file opens
anywhere with nothing beside it. The plot functions take plain arrays; the
procedure decides what to show:

* :func:`plot_velocity_windows` — speed and its moving average with the
  chosen extraction windows (seed 000 Figs. 3-4);
* :func:`plot_approach` — distance to the attained pose while approaching it,
  with the limit band, overshoot and settling marked (Figs. 5-6);
* :func:`plot_clusters` — attained positions per approach direction (Fig. 7);
* :func:`plot_bars` — per-pose or per-cycle values against a limit (Fig. 8:
  distance accuracy, posing time);
* :func:`plot_errors_before_after` — calibration errors before and after;
* :func:`plot_intervals` — figures with their expanded uncertainty, the
  limit and each figure's guard band (ISO 14253-1);
* :func:`plot_history` — one robot's figure over its runs against their date,
  the limit as a band, failures marked, overhauls as events.
"""

from __future__ import annotations

import html
import io
import math
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from station.shown import shown
from station.verdict import Outcome, combine, outcome_of


#: titles sit at the top of their axes (``set_title(y=...)``): matplotlib then skips measuring every tick
#: label to lift a title over top ticks, which these figures do not have (15 % of a cluster figure's time)
TITLE_Y = 1.0


def _figure(width_in: float = 8.0, height_in: float = 3.2, ncols: int = 1):
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, ncols, figsize=(width_in, height_in), squeeze=False)
    # fixed margins in inches (room for tick labels, an axis label, a title and 45-degree bar labels):
    # matplotlib's tight_layout measured every text of a figure first, 40 % of a report's plotting time
    left, right, bottom, top, gap = 0.8, 0.15, 0.75, 0.35, 0.55
    fig.subplots_adjust(left=left / width_in, right=1.0 - right / width_in, bottom=bottom / height_in,
                        top=1.0 - top / height_in, wspace=gap * ncols / (width_in - left - right))
    return fig, axes[0]


def _svg(fig) -> str:
    import matplotlib.pyplot as plt

    buf = io.StringIO()
    fig.savefig(buf, format="svg")
    plt.close(fig)
    text = buf.getvalue()
    return text[text.index("<svg"):]


#: most points a time trace keeps in a figure: about three per horizontal pixel of an 8-inch SVG at 72 dpi
TRACE_POINTS = 2000


def decimate_trace(t_s, y, max_points: int = TRACE_POINTS) -> tuple[np.ndarray, np.ndarray]:
    """A time trace thinned for drawing, its envelope kept: beyond ``2 max_points`` samples, the trace is
    cut into ``max_points / 2`` runs of equal length and each run's lowest and highest sample are kept in
    time order (a run without a finite sample keeps its first: a gap stays a gap).

    A 1 kHz tracker's speed over three cycles is 30,000 points, ten times what the figure can show;
    every extreme (a stop's dip, a peak) is still drawn.
    """
    t, v = np.asarray(t_s, float), np.asarray(y, float)
    n = v.size
    if n <= 2 * max_points:
        return t, v
    k = -(-n // (max_points // 2))  # samples per run
    runs = -(-n // k)
    pad = np.full(runs * k, np.nan)
    pad[:n] = v
    pad = pad.reshape(runs, k)
    finite = np.isfinite(pad)
    start = np.arange(runs) * k
    lo = start + np.argmin(np.where(finite, pad, np.inf), axis=1)
    hi = start + np.argmax(np.where(finite, pad, -np.inf), axis=1)
    empty = ~finite.any(axis=1)
    lo[empty] = hi[empty] = np.minimum(start[empty], n - 1)
    idx = np.unique(np.concatenate([lo, hi]))
    return t[idx], v[idx]


def plot_velocity_windows(
    t_s: np.ndarray, speed_mm_s: np.ndarray, windows: Sequence[tuple[float, float]], *, smooth_n: int = 21,
    title: str = "Speed and chosen extraction windows",
) -> str:
    """Speed, its moving average and the least-speed windows (seed 000 Figs. 3-4)."""
    t_s, speed = np.asarray(t_s, float), np.asarray(speed_mm_s, float)
    fig, (ax,) = _figure()
    ax.plot(*decimate_trace(t_s, speed), lw=0.6, color="0.6", label="speed")
    if speed.size >= smooth_n:
        kernel = np.ones(smooth_n) / smooth_n
        ax.plot(*decimate_trace(t_s, np.convolve(np.nan_to_num(speed), kernel, mode="same")), lw=1.0, color="C0",
                label=f"moving average ({smooth_n})")
    for k, (a, b) in enumerate(windows):
        ax.axvspan(a, b, color="C3", alpha=0.35, lw=0, label="extraction window" if k == 0 else None)
    ax.set_xlabel("t [s]")
    ax.set_ylabel("speed [mm/s]")
    ax.set_title(title, y=TITLE_Y)
    ax.legend(loc="upper right", fontsize=7)
    return _svg(fig)


def plot_approach(
    t_s: np.ndarray, dist_mm: np.ndarray, band_mm: float, *, t_enter_s: float | None = None,
    t_settle_s: float | None = None, title: str = "Approach",
) -> str:
    """Distance to the attained position while approaching it, with the limit band (Figs. 5-6)."""
    fig, (ax,) = _figure(6.0, 2.8)
    ax.plot(t_s, dist_mm, lw=0.9, color="C0", marker=".", ms=2)
    ax.axhline(band_mm, color="C3", lw=0.8, ls="--", label=f"limit band {band_mm:.3g} mm")
    if t_enter_s is not None:
        ax.axvline(t_enter_s, color="C2", lw=0.8, label="first entry")
    if t_settle_s is not None:
        ax.axvline(t_settle_s, color="C1", lw=0.8, label="stays inside")
    top = max(band_mm * 4, float(np.nanmin(dist_mm)) * 1.2 if np.size(dist_mm) else band_mm * 4)
    ax.set_ylim(0, top)
    ax.set_xlabel("t [s]")
    ax.set_ylabel("distance [mm]")
    ax.set_title(title, y=TITLE_Y)
    ax.legend(fontsize=7)
    return _svg(fig)


def plot_clusters(clusters: Mapping[str, np.ndarray], commanded_mm: np.ndarray | None = None, *, title: str = "Attained positions") -> str:
    """Attained positions per direction, projected on xy, xz and yz (Fig. 7); mm relative to their mean."""
    all_pts = np.vstack([np.asarray(v, float) for v in clusters.values()])
    centre = all_pts.mean(axis=0)
    fig, axes = _figure(9.0, 3.0, ncols=3)
    for ax, (i, j, lab) in zip(axes, ((0, 1, "x-y"), (0, 2, "x-z"), (1, 2, "y-z"))):
        for k, (name, pts) in enumerate(clusters.items()):
            p = np.asarray(pts, float) - centre
            # markers as lines without a line (a scatter collection per cluster cost twice as much to draw)
            ax.plot(p[:, i], p[:, j], ls="none", marker="o", ms=math.sqrt(8.0), mew=1.0, color=f"C{k}", label=name)
            ax.plot([p[:, i].mean()], [p[:, j].mean()], ls="none", marker="+", ms=math.sqrt(60.0), mew=1.5,
                    color=f"C{k}")
        if commanded_mm is not None:
            c = np.asarray(commanded_mm, float) - centre
            ax.plot([c[i]], [c[j]], ls="none", marker="x", ms=math.sqrt(50.0), mew=1.5, color="k", label="commanded")
        ax.set_title(f"{title} ({lab}) [mm]", fontsize=8, y=TITLE_Y)
        ax.set_aspect("equal", adjustable="datalim")
    axes[0].legend(fontsize=6)
    return _svg(fig)


def plot_bars(labels: Sequence[str], values: Sequence[float], *, limit: float | None = None, ylabel: str, title: str) -> str:
    """One bar per label with an optional limit line (Fig. 8 style)."""
    fig, (ax,) = _figure(6.0, 2.8)
    vals = np.asarray(values, float)
    colors = ["C3" if (limit is not None and v > limit) else "C0" for v in vals]
    ax.bar(range(len(vals)), vals, color=colors)
    ax.set_xticks(range(len(vals)), labels, fontsize=7, rotation=45 if len(vals) > 8 else 0)
    if limit is not None:
        ax.axhline(limit, color="C3", ls="--", lw=0.8, label=f"limit {limit:g}")
        ax.legend(fontsize=7)
    ax.set_ylabel(ylabel)
    ax.set_title(title, y=TITLE_Y)
    return _svg(fig)


def plot_intervals(labels: Sequence[str], values: Sequence[float], U: Sequence[float | None], *,
                   limit: float | None, ylabel: str, title: str) -> str:
    """Each figure with its interval figure +/- U, the limit, and the guard band limit -/+ U of each figure.

    A figure whose interval lies below the limit is conformance proven (green), above it non-conformance
    proven (red), across it not decided (orange); without a U it is drawn as a plain point.
    """
    fig, (ax,) = _figure(6.5, 3.0)
    vals = np.abs(np.asarray(values, float))
    us = np.array([np.nan if u is None else float(u) for u in U])
    x = np.arange(len(vals))
    for i, (v, u) in enumerate(zip(vals, us)):
        if limit is not None and np.isfinite(u):
            ax.add_patch(__import__("matplotlib.patches", fromlist=["Rectangle"]).Rectangle(
                (i - 0.35, limit - u), 0.7, 2 * u, color="C1", alpha=0.18, lw=0,
                label="guard band (limit -/+ U)" if i == 0 else None))
        if limit is None or not np.isfinite(u):
            color = "C0"
        elif v + u <= limit:
            color = "C2"
        elif v - u > limit:
            color = "C3"
        else:
            color = "C1"
        ax.errorbar([i], [v], yerr=None if not np.isfinite(u) else [[u], [u]], fmt="o", ms=4, color=color,
                    capsize=3, lw=1.0)
    if limit is not None:
        ax.axhline(limit, color="C3", ls="--", lw=0.8, label=f"limit {limit:g}")
        ax.legend(fontsize=7)
    ax.set_xticks(x, labels, fontsize=7, rotation=45 if len(vals) > 8 else 0)
    ax.set_xlim(-0.6, len(vals) - 0.4)
    ax.set_ylabel(ylabel)
    ax.set_title(title, y=TITLE_Y)
    return _svg(fig)


def history_figure(t_s: Sequence[float], values: Sequence[float], limits: Sequence[float | None],
                   failed: Sequence[bool], *, ylabel: str, title: str, events: Sequence[tuple[float, str]] = ()):
    """The figure of :func:`plot_history` (for a caller that needs the axes)."""
    import datetime as dt

    import matplotlib.dates as mdates

    fig, (ax,) = _figure(7.0, 2.6)
    when = [dt.datetime.fromtimestamp(float(t), tz=dt.timezone.utc) for t in t_s]
    v = np.asarray(values, float)
    bad = np.asarray(failed, bool)
    lims = [abs(float(x)) for x in limits if x is not None]
    if lims:
        lim = max(lims)
        low = -lim if (v.size and v.min() < 0) else 0.0
        ax.axhspan(low, lim, color="C2", alpha=0.12, lw=0, label=f"within the limit {lim:g}")
        ax.axhline(lim, color="C3", ls="--", lw=0.8)
        if low < 0:
            ax.axhline(low, color="C3", ls="--", lw=0.8)
    ax.plot(when, v, color="0.6", lw=0.8)
    ax.plot([w for w, b in zip(when, bad) if not b], v[~bad], "o", color="C0", ms=5, label="passed")
    if bad.any():
        ax.plot([w for w, b in zip(when, bad) if b], v[bad], "X", color="C3", ms=8, label="failed")
    for t, label in events:
        ax.axvline(dt.datetime.fromtimestamp(float(t), tz=dt.timezone.utc), color="k", ls=":", lw=0.8)
        ax.annotate(label, (dt.datetime.fromtimestamp(float(t), tz=dt.timezone.utc), 1.0),
                    xycoords=("data", "axes fraction"), fontsize=6, rotation=90, va="top", ha="right")
    # the axis takes every value and the whole band
    ymin = min([0.0, *(v.tolist()), *([-max(lims)] if lims and v.size and v.min() < 0 else [])])
    ymax = max([*(v.tolist()), *lims, 0.0])
    pad = 0.08 * (ymax - ymin or 1.0)
    ax.set_ylim(ymin - (pad if ymin < 0 else 0.0), ymax + pad)
    ax.xaxis.set_major_formatter(mdates.ConciseDateFormatter(ax.xaxis.get_major_locator()))
    ax.set_ylabel(ylabel)
    ax.set_title(title, fontsize=9, y=TITLE_Y)
    ax.legend(fontsize=6, loc="upper left")
    return fig


def plot_history(t_s: Sequence[float], values: Sequence[float], limits: Sequence[float | None],
                 failed: Sequence[bool], *, ylabel: str, title: str, events: Sequence[tuple[float, str]] = ()) -> str:
    """A figure over the runs of one robot against their date (``t_s`` epoch seconds, UTC): the band within
    the limit (``|value| <= limit``; down to ``-limit`` where a value is negative), passed runs as dots, failed
    runs marked, recorded ``events`` (overhauls) as vertical lines; the axis takes every value."""
    return _svg(history_figure(t_s, values, limits, failed, ylabel=ylabel, title=title, events=events))


def plot_xy(series: Sequence[tuple[str, np.ndarray, np.ndarray, str]], *, xlabel: str, ylabel: str, title: str) -> str:
    """Lines or points: ``series`` of (label, x, y, style) with style ``"-"`` (line) or ``"."`` (points)."""
    fig, (ax,) = _figure(7.0, 3.2)
    for k, (label, x, y, style) in enumerate(series):
        if style == ".":
            ax.plot(x, y, ".", ms=2, color=f"C{k}", label=label, alpha=0.6)
        else:
            ax.plot(x, y, "-", lw=1.2, color=f"C{k}", label=label)
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.set_title(title, y=TITLE_Y)
    ax.legend(fontsize=7)
    return _svg(fig)


def plot_load_displacement(curves: Mapping[str, tuple[np.ndarray, np.ndarray, np.ndarray]], *,
                           title: str = "Displacement against load (ISO 9283 clause 10)") -> str:
    """Displacement (um) against load (N) per direction: ``curves`` maps a direction to ``(load_N,
    displacement_mm, loading)``; the loading steps as a solid line, the unloading ones dashed (hysteresis)."""
    fig, (ax,) = _figure(7.0, 3.6)
    for k, (name, (F, d, up)) in enumerate(curves.items()):
        F, d, up = np.asarray(F, float), np.asarray(d, float) * 1000.0, np.asarray(up, bool)
        ax.plot(F[up], d[up], "o-", ms=3, lw=1.0, color=f"C{k}", label=f"{name} loading")
        idx = np.concatenate([np.flatnonzero(up)[-1:], np.flatnonzero(~up)])  # from the peak down
        ax.plot(F[idx], d[idx], "s--", ms=3, lw=1.0, color=f"C{k}", alpha=0.7, label=f"{name} unloading")
    ax.set_xlabel("load [N]")
    ax.set_ylabel("displacement along the load [um]")
    ax.set_title(title, y=TITLE_Y)
    ax.legend(fontsize=6, ncol=2)
    return _svg(fig)


def plot_errors_before_after(before: np.ndarray, after: np.ndarray, *, ylabel: str = "error [mm]", title: str = "Errors before and after calibration") -> str:
    fig, (ax,) = _figure(7.0, 2.8)
    ax.plot(np.abs(before), "o-", ms=3, lw=0.7, color="C0", label=f"before (mean {np.mean(np.abs(before)):.3g})")
    ax.plot(np.abs(after), "o-", ms=3, lw=0.7, color="C3", label=f"after (mean {np.mean(np.abs(after)):.3g})")
    ax.set_xlabel("measurement")
    ax.set_ylabel(ylabel)
    ax.set_title(title, y=TITLE_Y)
    ax.legend(fontsize=7)
    return _svg(fig)


#: a report's banner when none of its rows is judged (it has no verdict)
NO_LIMITS = "NO LIMITS"


@dataclass
class Report:
    """What goes into a run's HTML report."""

    title: str
    facts: dict[str, str] = field(default_factory=dict)
    #: rows with pose, name, value, unit, limit, passed; a row decided by a rule also has ``rule``, ``U`` and
    #: ``outcome`` (a :class:`station.verdict.Outcome`, or its stored text), which then says its verdict
    rows: list[Mapping] = field(default_factory=list)
    figures: list[tuple[str, str]] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    #: the run's verdict (:mod:`station.verdict`) when it was decided beyond these rows (cycles found,
    #: conformance, plant measurements); else judged from the rows
    outcome: Outcome | None = None
    #: why (one sentence each)
    reasons: list[str] = field(default_factory=list)

    @property
    def verdict(self) -> str:
        if self.outcome is not None:
            return str(self.outcome)
        shown = [o for o in map(shown_outcome, self.rows) if o is not None]
        return str(combine(shown)) if shown else NO_LIMITS


def shown_outcome(row: Mapping) -> Outcome | None:
    """The verdict a report row shows: its ``outcome`` when it has one, else its ``passed`` (None: no cell)."""
    if row.get("outcome"):
        return Outcome.parse(row["outcome"])
    return None if row.get("passed") is None else outcome_of(row["passed"])


def _cell_class(o: Outcome) -> str:
    """The CSS class of a row's verdict cell (``.pass``, ``.fail``, ``.und``)."""
    return o.word if o in (Outcome.PASS, Outcome.FAIL) else "und"


_CSS = """
body{font-family:system-ui,sans-serif;margin:2em;max-width:1100px;color:#222}
table{border-collapse:collapse;margin:1em 0}td,th{border:1px solid #ccc;padding:3px 8px;text-align:right}
th{background:#f3f3f3}td.l{text-align:left}.pass{color:#176317;font-weight:600}.fail{color:#b00020;font-weight:600}
.verdict{font-size:1.4em;padding:.3em .8em;display:inline-block;border-radius:4px}
.v-PASS{background:#dff3df}.v-FAIL{background:#fbe0e4}.v-NO{background:#eee}.v-NOT{background:#fff3cd}.v-ABORTED{background:#eee}
.und{color:#a35a00;font-weight:600}
figure{margin:1.5em 0}figcaption{font-size:.9em;color:#555}
"""


def render_html(report: Report) -> str:
    """The report as one HTML document (inline CSS and SVG); control characters in names shown escaped."""

    def e(text) -> str:
        return html.escape(shown(text, lines=True))

    parts = [
        "<!DOCTYPE html><html><head><meta charset='utf-8'>",
        f"<title>{e(report.title)}</title><style>{_CSS}</style></head><body>",
        f"<h1>{e(report.title)}</h1>",
        f"<p class='verdict v-{report.verdict.split()[0]}' id='verdict'>{e(report.verdict)}</p>",
    ]
    if report.reasons:
        parts.append("<ul id='reasons'>" + "".join(f"<li>{e(x)}</li>" for x in report.reasons) + "</ul>")
    parts.append("<table>")
    for k, v in report.facts.items():
        parts.append(f"<tr><th class='l'>{e(k)}</th><td class='l'>{e(str(v))}</td></tr>")
    with_u = any(r.get("U") is not None or (r.get("rule") is not None and r.get("outcome")) for r in report.rows)
    parts.append("</table><h2>Results</h2><table><tr><th>pose</th><th>characteristic</th><th>value</th>"
                 + ("<th>U (k=2)</th><th>interval</th>" if with_u else "")
                 + "<th>unit</th><th>limit</th><th>verdict</th></tr>")
    for r in report.rows:
        v = r.get("value")
        val = "n/a" if v is None or (isinstance(v, float) and not np.isfinite(v)) else f"{v:.4g}"
        lim = "" if r.get("limit") is None else f"{r['limit']:.4g}"
        o = shown_outcome(r)
        verdict = "" if o is None else f"<span class='{_cell_class(o)}'>{o.cell}</span>"
        unc = ""
        if with_u:
            U = r.get("U")
            unc = ("<td></td><td></td>" if U is None or v is None else
                   f"<td>{U:.2g}</td><td>{v - U:.4g} .. {v + U:.4g}</td>")
        parts.append(
            f"<tr><td class='l'>{e(str(r['pose']))}</td><td class='l'>{e(str(r['name']))}</td><td>{val}</td>{unc}"
            f"<td class='l'>{e(str(r.get('unit', '')))}</td><td>{lim}</td><td>{verdict}</td></tr>"
        )
    parts.append("</table>")
    for note in report.notes:
        parts.append(f"<p>{e(note)}</p>")
    for caption, svg in report.figures:
        parts.append(f"<figure>{svg}<figcaption>{e(caption)}</figcaption></figure>")
    parts.append(f"<p style='color:#888;font-size:.8em'>written {time.strftime('%Y-%m-%d %H:%M:%S')}</p></body></html>")
    return "\n".join(parts)


def write_report(report: Report, path: str | Path, option: str = "report") -> Path:
    """The HTML page of ``report`` at ``path``, written only over a regular file (:mod:`station.readers.out_files`)."""
    from station.readers.out_files import write_output

    return write_output(path, render_html(report), option)
