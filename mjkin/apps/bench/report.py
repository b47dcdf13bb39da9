"""What every benchmark shares: reports of titled tables, timing with the collector paused, the shared models."""

from __future__ import annotations

import gc
import math
import os
import time
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ...kinematics.tree import Tree, load

Row = dict[str, object]
Tables = dict[str, list[Row]]


@dataclass(frozen=True)
class Report:
    """What a benchmark measured: titled tables of rows, and the settings it ran with.

    ``published`` rows are figures quoted from elsewhere (with their source), printed
    beside the measured ones and kept apart from them in the JSON. ``notes`` are lines printed
    after the tables (e.g. why a peer has no row), kept as the JSON's ``"notes"`` when there are any.
    """

    tables: Tables
    settings: dict[str, object] = field(default_factory=dict)
    extra: dict[str, list[Row]] = field(default_factory=dict)
    notes: tuple[str, ...] = ()

    def as_json(self) -> dict[str, object]:
        """``{"rows": [...], "settings": {...}, ...}``: every measured row, then the extras (e.g. published)."""
        published = [id(r) for rows in self.extra.values() for r in rows]
        rows = [{k: None if isinstance(v, float) and math.isnan(v) else v for k, v in r.items()}
                for rows in self.tables.values() for r in rows if id(r) not in published]
        return {"rows": rows, "settings": self.settings, **self.extra, **({"notes": list(self.notes)} if self.notes
                                                                          else {})}


GC_NOTE = "Python's garbage collector off inside timed loops, as timeit does"


@contextmanager
def gc_paused() -> Iterator[None]:
    """Python's garbage collector off for a timed loop, as ``timeit`` does (collected first, restored after).

    With numba and MuJoCo loaded a full collection takes tens of milliseconds; one landing in a
    timed call would be charged to whichever solver happened to allocate at that moment.
    """
    was = gc.isenabled()
    gc.collect()
    gc.disable()
    try:
        yield
    finally:
        if was:
            gc.enable()


def seconds_per_call(fn: Callable[[], object], min_time: float = 0.2, repeat: int = 5) -> float:
    """Median of ``repeat`` runs of the mean time per call, each a loop of calls over at least ``min_time`` seconds."""
    return interleaved([fn], min_time, repeat)[0]


def interleaved(calls: Sequence[Callable[[], object]], min_time: float = 0.2, repeat: int = 5) -> list[float]:
    """Seconds per call of each of ``calls``: the median of ``repeat`` runs, the calls' runs taking turns.

    Each run is a loop of calls over at least ``min_time`` seconds; taking turns, a change in the machine's
    load falls on every call alike, so their ratios hold where their times do not.
    """
    for fn in calls:
        fn()  # warm caches
    runs: list[list[float]] = [[] for _ in calls]
    with gc_paused():
        for _ in range(repeat):
            for fn, out in zip(calls, runs, strict=True):
                n, start = 0, time.perf_counter()
                while True:
                    fn()
                    n += 1
                    elapsed = time.perf_counter() - start
                    if elapsed >= min_time:
                        break
                out.append(elapsed / n)
    return [float(np.median(r)) for r in runs]


def shared_models_dir() -> Path | None:
    """The mesh-free real robots: ``$MJKIN_SHARED_MODELS``, else ``../shared/models`` from here up."""
    env = os.environ.get("MJKIN_SHARED_MODELS")
    if env:
        return Path(env) if Path(env).is_dir() else None
    for base in (Path.cwd(), *Path.cwd().parents, Path(__file__).resolve().parent.parent):
        cand = base.parent / "shared" / "models"
        if cand.is_dir():
            return cand
    return None


def shared_model(relpath: str) -> Tree | None:
    """Load ``relpath`` from :func:`shared_models_dir`, or ``None`` when it is not there."""
    root = shared_models_dir()
    if root is None or not (root / relpath).is_file():
        return None
    return load(root / relpath)


def number_format(values: Sequence[float]) -> str:
    """One format for a column of floats.

    Exponents when the smallest non-zero value is below 0.001, whole numbers once the largest
    reaches 10 000, else the fixed decimals that give the smallest value 3 digits (at most 3);
    thousands separated by commas.
    """
    finite = [abs(v) for v in values if math.isfinite(v)]
    small = min((v for v in finite if v), default=1.0)
    if small < 1e-3:
        return ".2e"
    if max(finite, default=0.0) >= 1e4:
        return ",.0f"
    return f",.{min(max(2 - math.floor(math.log10(small)), 0), 3)}f"


def format_table(rows: list[Row]) -> str:
    """Rows as an aligned text table: one number format per column (:func:`number_format`), None and NaN as ``-``."""
    if not rows:
        return "(no rows)"
    cols = list(dict.fromkeys(c for r in rows for c in r))
    formats = {c: number_format([v for r in rows if isinstance(v := r.get(c), float)]) for c in cols}

    def cell(v: object, c: str) -> str:
        if v is None or isinstance(v, float) and math.isnan(v):
            return "-"
        return format(v, formats[c]) if isinstance(v, float) else str(v)

    cells = [[cell(r.get(c), c) for c in cols] for r in rows]
    widths = [max(len(c), *(len(r[i]) for r in cells)) for i, c in enumerate(cols)]
    line = "  ".join(c.rjust(w) for c, w in zip(cols, widths, strict=True))
    body = ["  ".join(v.rjust(w) for v, w in zip(r, widths, strict=True)) for r in cells]
    return "\n".join([line, "-" * len(line), *body])


# ----------------------------------------------------------------------------------------------- FK
