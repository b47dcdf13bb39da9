"""Retargeting a dataset: many clips onto one figure, a file per clip and a ``report.csv``, resumable, in parallel.

:func:`retarget_many` finds the clips (files and folders searched recursively for
:data:`~mjkin.motion.clips.CLIP_SUFFIXES`), retargets each (:func:`mjkin.retarget`),
measures it (:func:`mjkin.motion.retarget.report`) and writes ``OUT/<clip stem>.<format>``
(a clip in a sub-folder of its source folder keeps that sub-folder under OUT) and
``OUT/report.csv``, one row per clip. A clip that fails gets its one-line error in the
row's ``status`` and the others go on.

Every file is written atomically (:mod:`mjkin.runtime.files`) by the calling process,
``report.csv`` again after each clip from the rows of the clips done so far, so a run killed
at any moment loses no finished clip and leaves no half-written file. Each row records what its
file was made from (:data:`RECORD`: the model's digest, :func:`mjkin.retarget`'s options, mjkin's
version). Run again, a clip is skipped (its row kept) when its row in the previous ``report.csv``
is done (``ok`` or ``failed``), records what this run would make it from, and its file reads back
whole (:func:`read_motion`: its frames of this model's qpos); any other clip is redone, and
``overwrite=True`` redoes every clip. The output folder may be a source folder: the motion files
found there are not clips (an ``.npz`` holding ``qpos_names``, or one report.csv lists as an output).

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
import hashlib
import inspect
import io
import json
import multiprocessing
import os
import pickle
import sys
import warnings
import zipfile
from collections.abc import Collection, Iterable, Iterator, Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import dataclass, replace
from graphlib import CycleError, TopologicalSorter
from pathlib import Path
from typing import Any

import mujoco
import numpy as np
from numpy.typing import NDArray

from ..errors import InputError, MjkinError, MjkinIOError
from ..kinematics.qspace import BALL, FREE
from ..kinematics.tree import Tree, load, source_of
from ..runtime import ray_session, tier
from ..runtime.checks import check_choice, check_count
from ..runtime.files import LIMITS, as_path, kind_of, read_input_text, remove_stale_temps, write_text, write_with
from ..runtime.parallel import set_threads
from ..runtime.progress import track
from ..version import __version__
from . import bvh
from .clips import CLIP_SUFFIXES, read_clip
from .retarget import MAX_ERROR, check_max_error, read_mapping, report, retarget, verdict
from .terrain import Terrain
from .trajectory import Trajectory

FORMATS = ("npz", "csv", "json")
REPORT = "report.csv"
WARMUP_FRAMES = 3  # frames of the first clip retargeted here before workers start: every kernel compiled once
WARMUP_TRIES = 3  # clips tried for that warm-up (one may not read or map)
RECORD = ("model_sha256", "options", "mjkin_version")  # report.csv's columns of what a clip's file was made from
DONE = ("ok", "failed")  # the statuses of a clip whose file was written
OPTIONS = inspect.signature(retarget)  # what retarget takes, for the options given to retarget_many
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
    """What every clip's job shares: the figure, the body model of ``.npz`` clips, :func:`mjkin.retarget`'s options,
    and what a clip's file is made from (:func:`made_from`), by the clip's suffix.
    """  # noqa: D205

    tree: Tree
    body_model: str | None
    options: dict[str, Any]
    records: dict[str, dict[str, str]]

    def made_from(self, job: Job) -> dict[str, str]:
        """The :data:`RECORD` of ``job``'s file."""
        return self.records[job.path.suffix.lower()]

    def __reduce__(self) -> tuple[Any, tuple[Any, ...]]:
        """Pickle the figure as its ``MjModel``, its tree rebuilt where it arrives (as :mod:`mjkin.distributed` does).

        A pickled tree's arrays arrive read-only from Ray's object store, a type the kernels are not compiled for.
        """
        return _work, (self.tree.model, self.body_model, self.options, self.records)


def _work(model: mujoco.MjModel, body_model: str | None, options: dict[str, Any],
          records: dict[str, dict[str, str]]) -> Work:
    return Work(Tree.from_model(model), body_model, options, records)


# ------------------------------------------------------------------ what a file is made from
NOT_MADE_FROM = ("source", "tree", "model_source", "body_model", "max_error")  # retarget's arguments left out of
# the options recorded: the clip and figure (recorded apart), where the model was loaded from (its digest says what
# it is), the body model (its file's digest, for .npz clips only) and max_error (it judges the result, not makes it)


def model_digest(model: mujoco.MjModel) -> str:
    """SHA-256 (hex) of a compiled model as MuJoCo saves it (MJB).

    The compiled model holds every number the compiler made of the XML, its includes, defaults and mesh files: the
    same files give the same digest run after run, any change that reaches the model gives another (and so may a
    MuJoCo release that compiles differently). The XML text alone would miss its includes and meshes.
    """
    buffer = np.empty(mujoco.mj_sizeModel(model), dtype=np.uint8)
    mujoco.mj_saveModel(model, None, buffer)
    return hashlib.sha256(buffer.data).hexdigest()


def _file_digest(path: str) -> str:
    """SHA-256 (hex) of a file's bytes; its path when it cannot be read (each clip needing it then fails alone)."""
    digest = hashlib.sha256()
    try:
        with open(path, "rb") as f:
            for block in iter(lambda: f.read(1 << 20), b""):
                digest.update(block)
    except OSError:
        return path
    return digest.hexdigest()


def _plain(value: Any) -> Any:
    """A recorded option that JSON has no form for: numpy values as numbers, other objects (goals) by digest."""
    if isinstance(value, np.ndarray | np.generic):
        return value.tolist()
    return f"sha256 {hashlib.sha256(pickle.dumps(value)).hexdigest()}"


def made_from(tree: Tree, options: dict[str, Any], body_model: str | None) -> dict[str, dict[str, str]]:
    """What a clip's file is made from, by clip suffix: :data:`RECORD`'s columns as report.csv holds them.

    ``model_sha256`` (:func:`model_digest`), ``options``: :func:`mjkin.retarget`'s arguments, its defaults
    filled in, as JSON with sorted keys (a scene by its compiled model's digest, an ``.npz`` clip's body model by
    its file's; not those of :data:`NOT_MADE_FROM`), and ``mjkin_version``.
    """
    bound = OPTIONS.bind(None, tree, **options)
    bound.apply_defaults()
    made = {k: v for k, v in bound.arguments.items() if k not in NOT_MADE_FROM}
    if made.get("scene") is not None:
        scene = made["scene"]
        made["scene"] = model_digest((scene if isinstance(scene, Terrain) else Terrain.load(scene)).model)
    digest = model_digest(tree.model)
    by_clip = {".bvh": made, ".npz": {**made, "body_model": None if body_model is None else _file_digest(body_model)}}
    return {suffix: dict(zip(RECORD, (digest, json.dumps(m, sort_keys=True, default=_plain), __version__),
                             strict=True)) for suffix, m in by_clip.items()}


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


def read_motion(path: str | os.PathLike[str]) -> NDArray[np.float64]:
    """The qpos ``(F, nq)`` of a file :func:`write_motion` wrote (by suffix; an ``.npz`` read without pickles).

    Raises:
        MjkinError: the file is missing, damaged or not such a file (:class:`MjkinIOError` or :class:`InputError`).
    """
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix == ".json":
        return Trajectory.load(path).q
    if suffix not in (".npz", ".csv"):
        raise InputError(f"motion file {str(path)!r} must end in {', '.join('.' + f for f in FORMATS)}")
    try:
        if suffix == ".csv":
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")  # an empty file: no rows, as the check below says
                q = np.loadtxt(path, delimiter=",", ndmin=2)
        else:
            with np.load(path, allow_pickle=False) as f:
                q = f["qpos"]
    except (OSError, ValueError, EOFError, KeyError, zipfile.BadZipFile) as e:
        raise MjkinIOError(f"cannot read motion file {str(path)!r}: {_one_line(e)}") from None
    if q.ndim != 2 or q.dtype != np.float64:
        raise MjkinIOError(f"motion file {str(path)!r} holds qpos of shape {q.shape} ({q.dtype}), not (frames, nq)")
    return q


def _reads(path: Path, frames: Any, nq: int) -> bool:
    """Whether the motion file ``path`` reads back whole: ``frames`` rows of ``nq`` finite numbers."""
    try:
        q = read_motion(path)
    except MjkinError:
        return False
    return q.shape == (frames, nq) and bool(np.isfinite(q).all())


def _cell(value: Any) -> str:
    """A report value as a CSV cell: None empty, floats exactly (repr)."""
    return "" if value is None else repr(value) if isinstance(value, float) else str(value)


def _value(column: str, text: str) -> Any:
    """A cell of a previous report.csv as a value: empty None, a number as int or float, else the text."""
    if column in ("clip", "status", *RECORD) or text == "":
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
    """The rows of a previous report.csv by clip, those whose clip is done only (:data:`DONE`; {} when there is none).

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
                for row in rows if row.get("clip") and row.get("status") in DONE}
    except csv.Error as e:  # a cell over csv's field_size_limit, a NUL
        what = f"a cell over {csv.field_size_limit()} characters" if "field limit" in str(e) else str(e)
        raise MjkinIOError(f"cannot read the previous report {str(path)!r}: {what}; {hint}") from None


# ------------------------------------------------------------------ clips
def find_clips(sources: Sequence[str | os.PathLike[str]], skip: Path | None = None,
               outputs: Collection[Path] = ()) -> list[Job]:
    """The clips of ``sources``: files as given, folders searched recursively for :data:`CLIP_SUFFIXES`.

    Hidden files and folders (a name starting with ``.``), the folder ``skip`` (the output) and
    motion files (:func:`_is_output`; ``outputs``: the resolved paths a previous report.csv lists
    as outputs) are left out; a clip found twice counts once. Within a folder clips come by relative path.

    Raises:
        MjkinIOError: a source does not exist.
        InputError: a file source is not a clip, or a folder holds none.
    """
    jobs: list[Job] = []
    skip = None if skip is None else skip.resolve()
    for source in sources:
        src = Path(source)
        if src.is_dir():
            found = sorted((Job(p, p.relative_to(src).as_posix()) for p in _walk(src, skip, outputs)),
                           key=lambda j: j.name)
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


def _walk(folder: Path, skip: Path | None, outputs: Collection[Path]) -> Iterator[Path]:
    """Clip files under ``folder``, not hidden, not under ``skip``, not motion files (:func:`_is_output`)."""
    for root, dirs, files in os.walk(folder):
        dirs[:] = [d for d in dirs if not d.startswith(".") and Path(root, d).resolve() != skip]
        yield from (Path(root, f) for f in files if not f.startswith(".") and Path(f).suffix.lower() in CLIP_SUFFIXES
                    and not _is_output(Path(root, f), outputs))


def _is_output(path: Path, outputs: Collection[Path]) -> bool:
    """Whether ``path`` is a motion file (:func:`write_motion`), no clip: an ``.npz`` holding ``qpos_names`` (an
    AMASS clip holds none), or one that does not read as an ``.npz`` (a damaged file) at a path of ``outputs``.
    """  # noqa: D205
    if path.suffix.lower() != ".npz":
        return False
    try:
        with np.load(path, allow_pickle=False) as f:
            return "qpos_names" in f.files
    except (OSError, ValueError, EOFError, zipfile.BadZipFile):
        return path.resolve() in outputs


def _check_outputs(jobs: Sequence[Job], out: Path, fmt: str) -> None:
    """Refuse two clips writing one file, a clip writing over the report, or over a clip."""
    clips = {job.path.resolve(): job for job in jobs}
    taken: dict[Path, str] = {out / REPORT: "the report"}
    for job in jobs:
        dest = job.output(out, fmt)
        if dest.resolve() in clips:
            raise InputError(f"the {fmt} file of clip {str(job.path)!r} would overwrite clip "
                             f"{str(clips[dest.resolve()].path)!r}; write another format or into another folder")
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
    """Read, retarget and measure one clip: its report row (what it is made from, ``status`` ``ok``, ``failed``
    (:func:`mjkin.retarget`'s ``max_error``) or the error) and trajectory (or None).
    """  # noqa: D205
    try:
        clip = _read(work, job)
        traj, measured = _measure(work, clip)
    except Exception as e:  # noqa: BLE001 - one bad clip never stops the others: its row says why
        return {"clip": job.name, **work.made_from(job), "status": _one_line(e)}, None
    return {"clip": job.name, "frames": clip.frames, "fps": clip.fps, **measured, **work.made_from(job),
            "status": traj.meta["retarget"]["status"]}, traj


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
        OPTIONS.bind(None, tree, **options)
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
        overwrite: redo clips already done (by default a clip is skipped, its row kept, when its row in
            ``out/report.csv`` is done and records what this run would make its file from, and its file
            reads back whole; see the module).
        body_model: the SMPL/SMPL-H/SMPL-X model file for ``.npz`` clips
            (:func:`mjkin.motion.clips.read_clip`); without it they fail, each with its row.
        **options: :func:`mjkin.retarget`'s (``mapping``, ``scale``, ``max_speed``, ``clearance``, ``scene``,
            ``max_error``, ...); ``model_source`` defaults to where ``model`` loads from. A clip done before
            under another ``max_error`` is judged again from its row's ``frame_error_p95``, not redone. A
            mapping or scene file is read here first, so a bad one stops the run before any clip.

    Returns:
        The report's rows, one per clip in the order found: ``clip`` (path in ``out``'s terms),
        ``frames``, ``fps``, then :func:`mjkin.motion.retarget.report`'s keys (``frames_per_second``
        wall-clock, key-point errors, skate, ``floor_min``, ``limits``, speeds, self-contact, ...),
        what its file was made from (:data:`RECORD`, :func:`made_from`) and ``status``: ``ok``, ``failed``
        (its key points miss by more than ``max_error``: :func:`mjkin.motion.retarget.verdict`; its file is
        written) or the clip's one-line error (the measures then absent).

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
    max_error = check_max_error(options.get("max_error", MAX_ERROR))
    folder = as_path(out, "out")
    if folder.exists() and not folder.is_dir():
        raise InputError(f"output {str(folder)!r} is a file; several clips need a folder (made if missing)")
    try:
        given = [sources] if isinstance(sources, str | os.PathLike) else list(sources)
    except TypeError:
        raise InputError("sources must be a clip file or folder, "
                         f"or a list of them, got {type(sources).__name__}") from None
    try:
        previous = read_report(folder / REPORT)
    except MjkinIOError:
        if not overwrite:
            raise
        previous = {}  # rewritten anyway
    listed = {Job(folder, name).output(folder, fmt).resolve() for name in previous}  # outputs, no clips
    jobs = find_clips([as_path(s, "a source") for s in given], folder, listed)
    _check_outputs(jobs, folder, fmt)
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise MjkinIOError(f"cannot make the output folder {str(folder)!r}: {e.strerror or e}") from None
    for place in {job.output(folder, fmt).parent for job in jobs}:
        remove_stale_temps(place)  # what a killed run was writing
    report_file = ReportFile(folder / REPORT, [j.name for j in jobs])
    body_model = None if body_model is None else os.fspath(body_model)
    work = Work(tree, body_model, options, made_from(tree, options, body_model))
    for j in jobs:
        row = None if overwrite else previous.get(j.name)
        if (row is not None and all(row.get(k) == v for k, v in work.made_from(j).items())
                and isinstance(row.get("frame_error_p95"), float) and _reads(j.output(folder, fmt), row.get("frames"),
                                                                             tree.nq)):
            report_file.put({**row, "status": verdict(row["frame_error_p95"], max_error)})  # judged by this bound
    todo = [j for j in jobs if j.name not in report_file.rows]
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
