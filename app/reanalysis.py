"""Re-analysis of the archive: archived runs' raw samples through the current analysis code.

``station store reanalyze`` runs here. For every finished run of a procedure
whose spec says how its runs are re-analysed (``ProcedureSpec.reanalyse``,
:func:`procedures.registry.reanalysable`), that analysis is re-run from the
run's stored plan, journal outputs and raw samples, in parallel processes
(one per ``jobs``, each with its own store connection), and the result is
kept in ``reanalyses`` under :func:`analysis_version`, beside the original
``results``/``characteristics``, which are never touched: what was decided
stays as it was decided.

The analysis version is the package version plus a hash of the analysis
code's source (``station/analysis``, ``station/models`` and the modules of the
re-analysable procedures), so two results of the same code share a version and any change of
the code gives a new one.

Like :mod:`app.assemble`, this module is a front door's helper: it asks
the procedures' registry, never a procedure module or its step names (the
core never imports procedures).
"""

from __future__ import annotations

import hashlib
import importlib.util
import json
import math
import multiprocessing
import time
from collections.abc import Iterable
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass
from pathlib import Path


from procedures.registry import module_of, reanalysable
from station.errors import ConfigError, DataError
from station.store import RunStore
from station.numeric import json_default
from station.verdict import outcome_of

def analysis_version() -> str:
    """``<package version>+<sha1 of the analysis sources, 12 hex>``."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        pkg = version("robot-metrology-station")
    except PackageNotFoundError:
        pkg = "0"
    import station

    root = Path(station.__file__).resolve().parent
    files = sorted((root / "analysis").rglob("*.py")) + sorted((root / "models").rglob("*.py"))
    for module in sorted(module_of(name) for name in reanalysable()):
        spec = importlib.util.find_spec(module)
        if spec is not None and spec.origin:
            files.append(Path(spec.origin))
    h = hashlib.sha1()
    for f in files:
        h.update(f.name.encode())
        h.update(f.read_bytes())
    return f"{pkg}+{h.hexdigest()[:12]}"


@dataclass
class Reanalysis:
    run_id: str
    procedure: str
    version: str
    seconds: float
    n_values: int = 0
    max_change: float = 0.0
    verdict_changes: tuple[str, ...] = ()
    error: str | None = None
    skipped: bool = False


def reanalyze_run(target, run_id: str, version: str, force: bool = False) -> Reanalysis:
    """Re-analyse one run and keep the result under ``version``; compares with the original numbers."""
    t0 = time.perf_counter()
    with RunStore(target) as store:
        rec = store.run(run_id)
        spec = reanalysable()[rec.procedure]
        key, fn = spec.result_key, spec.reanalyse
        out = Reanalysis(run_id, rec.procedure, version, 0.0)
        if not force and store.backend.query(
                "SELECT 1 FROM reanalyses WHERE run_id=? AND key=? AND analysis_version=?", (run_id, key, version)):
            out.skipped = True
            return out
        try:
            result, rows = fn(store, run_id)
        except (DataError, KeyError, ValueError) as exc:
            out.error = f"{type(exc).__name__}: {exc}"
            out.seconds = time.perf_counter() - t0
            return out
        value = json.loads(json.dumps({"result": result, "characteristics": rows}, default=json_default))
        store.put_reanalysis(run_id, key, version, value)
        before = {(c["pose"], c["name"]): c for c in store.characteristics(run_id)}
        changes, flips = [], []
        for r in rows:
            old = before.get((r["pose"], r["name"]))
            if old is None:
                continue
            if _finite(old["value"]) and _finite(r["value"]):
                changes.append(abs(float(r["value"]) - float(old["value"])))
            if old["passed"] is not None and r["passed"] is not None and bool(old["passed"]) != bool(r["passed"]):
                flips.append(f"{r['pose']} {r['name']}: {outcome_of(old['passed']).cell} -> "
                             f"{outcome_of(r['passed']).cell}")
        out.n_values, out.max_change = len(rows), max(changes, default=0.0)
        out.verdict_changes = tuple(flips)
    out.seconds = time.perf_counter() - t0
    return out


def runs_to_reanalyze(store: RunStore, run_ids: Iterable[str] | None = None,
                      procedure: str | None = None) -> list[str]:
    analyses = reanalysable()
    if procedure is not None and procedure not in analyses:
        raise ConfigError(f"no re-analysis for procedure {procedure!r} (have: {', '.join(analyses)})")
    if run_ids:
        ids = list(run_ids)
        for r in ids:
            rec = store.run(r)
            if rec.procedure not in analyses:
                raise ConfigError(f"run {r} is a {rec.procedure} run; no re-analysis for it "
                                  f"(have: {', '.join(analyses)})")
        return ids
    return [r.run_id for r in store.runs() if r.status == "done" and r.procedure in analyses
            and (procedure is None or r.procedure == procedure)]


def reanalyze(target, run_ids: list[str], *, jobs: int = 1, force: bool = False) -> list[Reanalysis]:
    """Re-analyse ``run_ids`` of the store at ``target`` in ``jobs`` processes (1: in this process)."""
    if jobs < 1:
        raise ConfigError(f"jobs must be at least 1, got {jobs}")
    version = analysis_version()
    target = str(target)
    if jobs == 1 or len(run_ids) <= 1:
        return [reanalyze_run(target, r, version, force) for r in run_ids]
    ctx = multiprocessing.get_context("spawn")  # no inherited connections or threads
    with ProcessPoolExecutor(max_workers=jobs, mp_context=ctx) as pool:
        return list(pool.map(reanalyze_run, [target] * len(run_ids), run_ids, [version] * len(run_ids),
                             [force] * len(run_ids)))


def _finite(v) -> bool:
    return v is not None and isinstance(v, (int, float)) and math.isfinite(v)


