"""Retargeting a dataset: many clips onto one figure, a file per clip and a ``report.csv``, resumable, in parallel.

:func:`retarget_many` finds the clips (files and folders searched recursively for
:data:`~mjkin.motion.clips.CLIP_SUFFIXES`), retargets each (:func:`mjkin.retarget`),
measures it (:func:`mjkin.motion.retarget.report`) and writes ``OUT/<clip stem>.<format>``
(a clip in a sub-folder of its source folder keeps that sub-folder under OUT) and
``OUT/report.csv``, one row per clip. A clip that fails gets its one-line error in the
row's ``status`` and the others go on.

Every file is written atomically (:mod:`mjkin.runtime.files`) by the calling process,
``report.csv`` again after each clip from the rows of the clips done so far, so a run killed
at any moment loses no finished clip and leaves no half-written file. Run again, a clip whose
file exists and whose row in the previous ``report.csv`` says ``ok`` is skipped (its row kept);
``overwrite=True`` redoes every clip.

Clips run in this process, in local worker processes (forked after this process has
compiled the kernels on a few frames, so they compile nothing) or as Ray tasks (the
``ray`` extra: the clips must be on storage the workers see; the files are written here).

Formats (:func:`write_motion`, by suffix):

- ``npz``: ``qpos (F, nq)`` float64 (MuJoCo's qpos per frame), ``fps`` (a scalar),
  ``qpos_names (nq,)`` (:func:`qpos_names`), ``body_names (nbody,)`` and
  ``body_positions (F, nbody, 3)`` (world, m; index = MuJoCo body id, 0 the world);
- ``csv``: one row of ``qpos`` per frame, comma-separated, after ``#`` lines giving the
  model, ``fps`` and the names: ``numpy.loadtxt(path, delimiter=",")`` reads ``(F, nq)``;
- ``json``: the trajectory script (:meth:`mjkin.motion.Trajectory.save`), for ``mjkin replay``.
"""

from __future__ import annotations

import csv
import inspect
import io
import multiprocessing
import os
import sys
from collections.abc import Iterable, Iterator, Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import dataclass, replace
from graphlib import CycleError, TopologicalSorter
from pathlib import Path
from typing import Any

import mujoco
import numpy as np

from ..errors import InputError, MjkinError, MjkinIOError
from ..kinematics.qspace import BALL, FREE
from ..kinematics.tree import Tree, load, source_of
from ..runtime import ray_session, tier
from ..runtime.checks import check_choice, check_count
from ..runtime.files import LIMITS, as_path, kind_of, read_input_text, remove_stale_temps, write_text, write_with
from ..runtime.parallel import set_threads
from ..runtime.progress import track
from . import bvh
from .clips import CLIP_SUFFIXES, read_clip
from .retarget import read_mapping, report, retarget
from .terrain import Terrain
from .trajectory import Trajectory

FORMATS = ("npz", "csv", "json")
REPORT = "report.csv"
WARMUP_FRAMES = 3  # frames of the first clip retargeted here before workers start: every kernel compiled once
WARMUP_TRIES = 3  # clips tried for that warm-up (one may not read or map)
Outcome = tuple[dict[str, Any], Trajectory | None]  # a clip's report row and trajectory (None when it failed)
COORDS = {FREE: ("x", "y", "z", "qw", "qx", "qy", "qz"), BALL: ("qw", "qx", "qy", "qz")}  # suffixes per coordinate


@dataclass(frozen=True)
class Job:
    """One clip: its file and ``name``, its path relative to the folder it was found in (posix), or its file name."""

    path: Path
    name: str

    def output(self, out: Path, fmt: str) -> Path:
        """The clip's file under ``out``: its name with the format's suffix."""
        return out / Path(self.name).with_suffix(f".{fmt}")


@dataclass(frozen=True)
class Work:
    """What every clip's job shares: the figure, the body model of ``.npz`` clips, :func:`mjkin.retarget`'s options."""

    tree: Tree
    body_model: str | None
    options: dict[str, Any]

    def __reduce__(self) -> tuple[Any, tuple[Any, ...]]:
        """Pickle the figure as its ``MjModel``, its tree rebuilt where it arrives (as :mod:`mjkin.distributed` does).

        A pickled tree's arrays arrive read-only from Ray's object store, a type the kernels are not compiled for.
        """
        return _work, (self.tree.model, self.body_model, self.options)


def _work(model: mujoco.MjModel, body_model: str | None, options: dict[str, Any]) -> Work:
    return Work(Tree.from_model(model), body_model, options)


# ------------------------------------------------------------------ files
def qpos_names(tree: Tree) -> list[str]:
    """Names of the ``nq`` coordinates of qpos, in its order.

    A hinge's or slide's joint name; a ball joint's ``NAME_qw``, ``NAME_qx``, ``NAME_qy``, ``NAME_qz``; a free
    joint's ``NAME_x``, ``NAME_y``, ``NAME_z`` (m) then ``NAME_qw`` .. ``NAME_qz``; an unnamed joint is ``joint<id>``.
    """
    out: list[str] = []
    for j, name in enumerate(tree.names("joint")):
        name = name or f"joint{j}"
        suffixes = COORDS.get(int(tree.jnt_type[j]))
        out.extend([f"{name}_{s}" for s in suffixes] if suffixes else [name])
    return out


def write_motion(path: str | os.PathLike[str], traj: Trajectory, tree: Tree, fps: float) -> Path:
    """Write ``traj`` (recorded on ``tree``, ``fps`` frames per second) atomically as ``.npz``, ``.csv`` or ``.json``.

    See the module for what each format holds.

    Raises:
        InputError: another suffix.
        MjkinIOError: the file cannot be written.
    """
    suffix = Path(path).suffix.lower()
    if suffix == ".json":
        return traj.save(path)
    q = np.asarray(traj.q, dtype=np.float64)
    names = qpos_names(tree)
    if suffix == ".npz":
        bodies = [n or f"body{b}" for b, n in enumerate(tree.names("body"))]
        arrays: dict[str, Any] = {"qpos": q, "fps": np.float64(fps), "qpos_names": np.array(names),
                                  "body_names": np.array(bodies), "body_positions": tree.fk(q)[..., :3, 3]}
        return write_with(path, lambda p: np.savez(p, **arrays))
    if suffix == ".csv":
        head = (f"mjkin retarget onto {tree.name or 'the model'}: one row of qpos ({tree.nq} numbers) per frame, "
                f"numpy.loadtxt(path, delimiter=',')\nfps: {fps:.17g}\n{','.join(names)}")
        buf = io.StringIO()
        np.savetxt(buf, q, fmt="%.17g", delimiter=",", header=head)
        return write_text(path, buf.getvalue())
    raise InputError(f"motion file {str(path)!r} must end in {', '.join('.' + f for f in FORMATS)}")


def _cell(value: Any) -> str:
    """A report value as a CSV cell: None empty, floats exactly (repr)."""
    return "" if value is None else repr(value) if isinstance(value, float) else str(value)


def _value(column: str, text: str) -> Any:
    """A cell of a previous report.csv as a value: empty None, a number as int or float, else the text."""
    if column in ("clip", "status") or text == "":
        return None if text == "" else text
    for kind in (int, float):
        try:
            return kind(text)
        except ValueError:
            continue
    return text


def columns(rows: Iterable[dict[str, Any]]) -> list[str]:
    """The report's columns: every row's keys in an order that keeps each row's (report's own), ``status`` last.

    Rows that disagree on the order (a report.csv of an older mjkin) give the keys in the order first seen.
    """
    order: TopologicalSorter[str] = TopologicalSorter()
    seen: dict[str, None] = {}
    for row in rows:
        keys = list(row)
        seen.update(dict.fromkeys(keys))
        for k, key in enumerate(keys):
            order.add(key, *keys[k - 1:k])  # after the key before it in this row
    try:
        cols = list(order.static_order())
    except CycleError:
        cols = list(seen)
    return [c for c in cols if c != "status"] + ["status"]


def _line(cells: Sequence[str]) -> str:
    buf = io.StringIO()
    csv.writer(buf, lineterminator="\n").writerow(cells)
    return buf.getvalue()


class ReportFile:
    """``report.csv``: a row per clip, in the clips' ``order``, rewritten atomically by :meth:`write`.

    Columns come from :func:`columns` (an absent value is an empty cell); each row is formatted once
    (again only when a row brings a new column), so a rewrite after each of thousands of clips costs
    little more than writing the file.
    """

    def __init__(self, path: Path, order: Sequence[str]) -> None:
        self.path, self.order = path, list(order)
        self.rows: dict[str, dict[str, Any]] = {}
        self.cols: list[str] = []
        self.lines: dict[str, str] = {}

    def put(self, row: dict[str, Any]) -> None:
        """Add or replace the row of clip ``row["clip"]``."""
        if not set(row) <= set(self.cols):
            self.cols = columns([dict.fromkeys(self.cols), row])  # the columns so far keep every earlier row's order
            self.lines.clear()
        self.rows[row["clip"]] = row
        self.lines.pop(row["clip"], None)

    def write(self) -> Path:
        """Write the rows put so far."""
        done = [n for n in self.order if n in self.rows]
        for n in done:
            if n not in self.lines:
                self.lines[n] = _line([_cell(self.rows[n].get(c)) for c in self.cols])
        text = _line(self.cols) + "".join(self.lines[n] for n in done)
        # a clip's name in bytes that are not UTF-8 (decoded by Python as surrogates) is written as those bytes
        return write_with(self.path, lambda p: p.write_text(text, encoding="utf-8", errors="surrogateescape"))


def read_report(path: Path) -> dict[str, dict[str, Any]]:
    """The rows of a previous report.csv by clip, those whose status is ``ok`` only ({} when there is none).

    Raises:
        MjkinIOError: it exists but cannot be read.
    """
    if not os.path.lexists(path):
        return {}
    hint = "delete it or give overwrite"
    text = read_input_text(path, "previous report", LIMITS["report"], errors="surrogateescape", hint=hint)
    try:
        rows = csv.DictReader(io.StringIO(text))
        return {row["clip"]: {k: _value(k, v or "") for k, v in row.items() if k is not None}
                for row in rows if row.get("clip") and row.get("status") == "ok"}
    except csv.Error as e:  # a cell over csv's field_size_limit, a NUL
        what = f"a cell over {csv.field_size_limit()} characters" if "field limit" in str(e) else str(e)
        raise MjkinIOError(f"cannot read the previous report {str(path)!r}: {what}; {hint}") from None


# ------------------------------------------------------------------ clips
def find_clips(sources: Sequence[str | os.PathLike[str]], skip: Path | None = None) -> list[Job]:
    """The clips of ``sources``: files as given, folders searched recursively for :data:`CLIP_SUFFIXES`.

    Hidden files and folders (a name starting with ``.``) and the folder ``skip`` (the output)
    are left out; a clip found twice counts once. Within a folder clips come by relative path.

    Raises:
        MjkinIOError: a source does not exist.
        InputError: a file source is not a clip, or a folder holds none.
    """
    jobs: list[Job] = []
    skip = None if skip is None else skip.resolve()
    for source in sources:
        src = Path(source)
        if src.is_dir():
            found = sorted((Job(p, p.relative_to(src).as_posix()) for p in _walk(src, skip)), key=lambda j: j.name)
            if not found:
                raise InputError(f"folder {str(src)!r} holds no clips ({', '.join(CLIP_SUFFIXES)} files, searched "
                                 "recursively)")
            jobs.extend(found)
        elif src.is_file():
            if src.suffix.lower() not in CLIP_SUFFIXES:
                raise InputError(f"clip {str(src)!r} must be a {' or '.join(CLIP_SUFFIXES)} file (or a folder)")
            jobs.append(Job(src, src.name))
        elif kind_of(src):  # a FIFO, a device: say so, never read it
            raise MjkinIOError(f"clip {str(src)!r} is {kind_of(src)}, not a regular file; give the clip file itself")
        else:
            raise MjkinIOError(f"clip or folder not found: {str(src)!r}")
    unique: dict[Path, Job] = {}
    for job in jobs:
        unique.setdefault(job.path.resolve(), job)
    return list(unique.values())


def _walk(folder: Path, skip: Path | None) -> Iterator[Path]:
    """Clip files under ``folder``, not hidden, not under ``skip``."""
    for root, dirs, files in os.walk(folder):
        dirs[:] = [d for d in dirs if not d.startswith(".") and Path(root, d).resolve() != skip]
        yield from (Path(root, f) for f in files if not f.startswith(".") and Path(f).suffix.lower() in CLIP_SUFFIXES)


def _check_outputs(jobs: Sequence[Job], out: Path, fmt: str) -> None:
    """Refuse two clips writing one file (or a clip writing over the report)."""
    taken: dict[Path, str] = {out / REPORT: "the report"}
    for job in jobs:
        dest = job.output(out, fmt)
        if dest in taken:
            raise InputError(f"{taken[dest]} and clip {str(job.path)!r} would both write {str(dest)!r}; rename the "
                             "clip or retarget it into another folder")
        taken[dest] = f"clip {str(job.path)!r}"


# ------------------------------------------------------------------ running
def _one_line(error: BaseException) -> str:
    text = " ".join(str(error).split())
    return text if isinstance(error, MjkinError) else f"{type(error).__name__}: {text}"


def _read(work: Work, job: Job) -> bvh.Clip:
    # a body model is for SMPL .npz clips only: a BVH beside them in the folder is read without it
    return read_clip(job.path, work.body_model if job.path.suffix.lower() == ".npz" else None)


def _measure(work: Work, clip: bvh.Clip) -> tuple[Trajectory, dict[str, Any]]:
    """The clip retargeted and its report, kernels compiled in this process if not cached (``tier.waiting``)."""
    with tier.waiting():
        traj = retarget(clip, work.tree, **work.options)
        return traj, report(work.tree, traj)


def retarget_clip(work: Work, job: Job) -> Outcome:
    """Read, retarget and measure one clip: its report row (``status`` ``ok`` or the error) and trajectory (or None)."""
    try:
        clip = _read(work, job)
        traj, measured = _measure(work, clip)
    except Exception as e:  # noqa: BLE001 - one bad clip never stops the others: its row says why
        return {"clip": job.name, "status": _one_line(e)}, None
    return {"clip": job.name, "frames": clip.frames, "fps": clip.fps, **measured, "status": "ok"}, traj


def _warm_up(work: Work, jobs: Sequence[Job]) -> None:
    """Compile every kernel here, on the first few frames of the first clip that works (of :data:`WARMUP_TRIES`)."""
    for job in jobs[:WARMUP_TRIES]:
        try:
            clip = _read(work, job)
            _measure(work, replace(clip, values=clip.values[:WARMUP_FRAMES]))
            return
        except Exception:  # noqa: BLE001 - the clip's own job reports its error
            continue


_WORK: Work | None = None  # a worker process's shared work (set by _start_worker)


def _start_worker(work: Work) -> None:
    global _WORK
    _WORK = work
    set_threads(1)  # one clip per process: the processes are the parallelism


def _pooled(job: Job) -> Outcome:
    assert _WORK is not None, "the worker was started without its work"
    return retarget_clip(_WORK, job)


def _in_processes(work: Work, jobs: Sequence[Job], workers: int) -> Iterator[tuple[Job, Outcome]]:
    """``(job, retarget_clip(work, job))`` as local worker processes finish them."""
    _warm_up(work, jobs)
    # fork on Linux: the workers start with the kernels compiled above and mjkin imported
    context = multiprocessing.get_context("fork" if sys.platform.startswith("linux") else None)
    pool = ProcessPoolExecutor(min(workers, len(jobs)), mp_context=context, initializer=_start_worker,
                               initargs=(work,))
    try:
        futures = {pool.submit(_pooled, job): job for job in jobs}
        for done in as_completed(futures):
            yield futures[done], done.result()
    finally:
        pool.shutdown(cancel_futures=True)


def _on_ray(work: Work, jobs: Sequence[Job], workers: int | None, address: str | None) -> Iterator[tuple[Job, Outcome]]:
    """``(job, retarget_clip(work, job))`` as Ray tasks (one CPU each, ``workers`` at once at most) finish them."""
    if not jobs:
        return
    ray_session.connect(address)  # says what to install when Ray is missing
    ray = ray_session.module()
    _warm_up(work, jobs)  # a local cluster's workers then load the kernels from the disk cache
    task = ray.remote(num_cpus=1)(retarget_clip)
    shared = ray.put(work)
    waiting, running = iter(jobs), dict[Any, Job]()
    while True:
        while workers is None or len(running) < workers:
            job = next(waiting, None)
            if job is None:
                break
            running[task.remote(shared, job)] = job
        if not running:
            return
        done, _ = ray.wait(list(running), num_returns=1)
        yield running.pop(done[0]), ray_session.unwrap(done[0])


def _check_options(tree: Tree, options: dict[str, Any]) -> None:
    """Refuse options :func:`mjkin.retarget` does not take, before any clip runs."""
    try:
        inspect.signature(retarget).bind(None, tree, **options)
    except TypeError as e:
        raise InputError(f"retarget_many: {e} (options are mjkin.retarget's)") from None


def retarget_many(sources: str | os.PathLike[str] | Sequence[str | os.PathLike[str]],
                  model: str | os.PathLike[str] | Tree, out: str | os.PathLike[str], *, format: str = "npz",
                  workers: int | None = None, ray: bool | str | None = None, overwrite: bool = False,
                  body_model: str | os.PathLike[str] | None = None, **options: Any) -> list[dict[str, Any]]:
    """Retarget every clip of ``sources`` onto ``model``: ``out/<clip stem>.<format>`` each, and ``out/report.csv``.

    Args:
        sources: clip files (``.bvh``, AMASS/SMPL ``.npz``) and folders, searched recursively
            (hidden names and ``out`` left out). A clip in a sub-folder keeps it under ``out``.
        model: a bundled model's name, an MJCF/URDF path or a :class:`~mjkin.Tree`.
        out: the folder for the files (made if missing).
        format: ``npz``, ``csv`` or ``json`` (see the module).
        workers: clips at once: local processes (None: 1, in this process), or with ``ray``
            Ray tasks (None: as many as the cluster runs).
        ray: run the clips as Ray tasks: True attaches to the running Ray session or starts a
            local one, a string is a cluster's address (the ``ray`` extra).
        overwrite: redo clips already done (by default a clip whose file exists and whose row in
            ``out/report.csv`` says ``ok`` is skipped, its row kept).
        body_model: the SMPL/SMPL-H/SMPL-X model file for ``.npz`` clips
            (:func:`mjkin.motion.clips.read_clip`); without it they fail, each with its row.
        **options: :func:`mjkin.retarget`'s (``mapping``, ``scale``, ``max_speed``, ``clearance``, ``scene``,
            ...); ``model_source`` defaults to where ``model`` loads from. A mapping or scene file is read
            here first, so a bad one stops the run before any clip.

    Returns:
        The report's rows, one per clip in the order found: ``clip`` (path in ``out``'s terms),
        ``frames``, ``fps``, then :func:`mjkin.motion.retarget.report`'s keys (``frames_per_second``
        wall-clock, key-point errors, skate, ``floor_min``, ``limits``, speeds, self-contact, ...)
        and ``status`` (``ok`` or the clip's one-line error, the other keys then absent).

    Raises:
        MjkinIOError: a source, mapping or scene file does not exist, or a file cannot be written.
        InputError: a bad format, workers or option, a folder without clips, ``out`` a file, or
            two clips that would write the same file.
        ModelError: the model (or scene) cannot be loaded.
    """
    fmt = check_choice(format, "format", FORMATS)
    if workers is not None:
        check_count(workers, "workers")
    tree = model if isinstance(model, Tree) else load(model)
    if not isinstance(model, Tree):
        options.setdefault("model_source", source_of(os.fspath(model)))
    if isinstance(options.get("mapping"), str | os.PathLike):
        options["mapping"] = read_mapping(options["mapping"])  # once, and a missing file before any work
    if isinstance(options.get("scene"), str | os.PathLike):
        Terrain.load(options["scene"])  # a bad scene before any work (then cached by file, for forked workers too)
    _check_options(tree, options)
    folder = as_path(out, "out")
    if folder.exists() and not folder.is_dir():
        raise InputError(f"output {str(folder)!r} is a file; several clips need a folder (made if missing)")
    try:
        given = [sources] if isinstance(sources, str | os.PathLike) else list(sources)
    except TypeError:
        raise InputError(f"sources must be a clip file or folder, or a list of them, got {type(sources).__name__}") \
            from None
    jobs = find_clips([as_path(s, "a source") for s in given], folder)
    _check_outputs(jobs, folder, fmt)
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise MjkinIOError(f"cannot make the output folder {str(folder)!r}: {e.strerror or e}") from None
    for place in {job.output(folder, fmt).parent for job in jobs}:
        remove_stale_temps(place)  # what a killed run was writing
    report_file = ReportFile(folder / REPORT, [j.name for j in jobs])
    previous = {} if overwrite else read_report(report_file.path)
    for j in jobs:
        if j.name in previous and j.output(folder, fmt).is_file():
            report_file.put(previous[j.name])
    todo = [j for j in jobs if j.name not in report_file.rows]
    work = Work(tree, None if body_model is None else os.fspath(body_model), options)
    # largest first, so that no worker ends on a long clip alone (a clip gone since is left to fail in its job)
    largest_first = sorted(todo, key=lambda j: -(j.path.stat().st_size if j.path.is_file() else 0))
    if ray:
        results = _on_ray(work, largest_first, workers, None if ray is True else str(ray))
    elif (workers or 1) > 1 and len(todo) > 1:
        results = _in_processes(work, largest_first, workers or 1)
    else:
        results = ((job, retarget_clip(work, job)) for job in todo)
    for job, (row, traj) in track(results, "clips", total=len(todo)):
        if traj is not None:
            dest = job.output(folder, fmt)
            dest.parent.mkdir(parents=True, exist_ok=True)
            write_motion(dest, traj, tree, row["fps"])
        report_file.put(row)
        report_file.write()
    if not todo:  # all done before: the report of this run's clips
        report_file.write()
    return [report_file.rows[j.name] for j in jobs]
