"""The numba set-up: the cache guard (caches go when any source changes, and only then), borrowed views, entries."""

import numba
import numpy as np

import mjkin
from mjkin.goals import Position
from mjkin.ik.packed import FIELDS, Packed
from mjkin.jit import borrowed, borrowed_fields, drop_stale_caches, entry, keep_alive


def test_caches_are_dropped_when_any_source_changes(tmp_path):
    (tmp_path / "fk.py").write_text("x = 1\n")
    (tmp_path / "sub").mkdir()
    (tmp_path / "sub" / "kernel.py").write_text("y = 2\n")
    cache = tmp_path / "sub" / "__pycache__"
    cache.mkdir()
    index, data = cache / "kernel.solve-1.py311.nbi", cache / "kernel.solve-1.py311.1.nbc"
    assert drop_stale_caches(tmp_path)  # no digest yet: caches of unknown sources go
    index.write_bytes(b"i")
    data.write_bytes(b"d")
    assert not drop_stale_caches(tmp_path) and index.exists() and data.exists()  # unchanged: kept
    (tmp_path / "fk.py").write_text("x = 3\n")  # another file than the cached kernel's
    assert drop_stale_caches(tmp_path)
    assert not index.exists() and not data.exists()
    assert not drop_stale_caches(tmp_path)


def test_numba_cache_dir_is_honoured(tmp_path, monkeypatch):
    from mjkin.jit import cache_dir

    pkg = tmp_path / "src" / "mjkin"
    pkg.mkdir(parents=True)
    (pkg / "a.py").write_text("x = 1\n")
    assert cache_dir(pkg) == pkg
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path / "cache"))
    target = cache_dir(pkg)
    assert target == tmp_path / "cache" / pkg.relative_to(pkg.anchor)
    target.mkdir(parents=True)
    stale = target / "a.f-1.py311.nbi"
    stale.write_bytes(b"i")
    assert drop_stale_caches(pkg) and not stale.exists()  # the caches numba would read are the ones checked
    assert (target / "mjkin-sources.sha256").is_file() and not (pkg / "__pycache__").exists()


def test_warmup_compiles_every_kernel_mjkin_runs():
    from mjkin.apps.warmup import warmup
    from mjkin.ik.compiled import kernels
    from mjkin.kinematics.fk import fk_kernel

    assert warmup() > 0
    assert kernels().solve_packed.signatures and fk_kernel.signatures


def test_borrowed_views_read_and_write_their_owners():
    """``borrowed`` views (no reference counts) see and change the arrays they were made from, nested tuples too."""
    @numba.njit
    def fill(a):
        own = (np.zeros(3), (np.ones((2, 2)), 7))
        z, (o, k) = borrowed(own)
        b = borrowed(a)
        for i in range(3):
            z[i] = b[i] * k
            b[i] += o[0, 0]
        total = z.sum() + o.sum()
        keep_alive(own)
        return total

    a = np.arange(3.0)
    assert fill(a) == 3 * 7 + 4.0
    assert np.array_equal(a, np.arange(3.0) + 1.0)


def test_borrowed_fields_are_the_structrefs_own_arrays():
    """A packed problem's fields, read without reference counts, are its arrays: what is written there is seen."""
    @numba.njit
    def first_q_plus_one(pk):
        fields = borrowed_fields(pk)
        q = fields[8]
        q[0, 0] += 1.0
        return fields[4], q[0, 0]

    problem = mjkin.Problem(mjkin.load("arm7"), Position("ee", (0.3, 0.1, 0.4)))
    problem.solve()
    packed, arrays = problem._run.one
    assert isinstance(packed, Packed) and FIELDS[8] == "q" and FIELDS[4] == "max_iters"
    before = arrays[1][0, 0]
    assert first_q_plus_one(packed) == (problem._run.max_iters, before + 1.0)
    assert arrays[1][0, 0] == before + 1.0


def test_an_entry_is_the_compiled_code_without_the_dispatch():
    @numba.njit
    def scaled(a, k):
        return a.sum() * k

    a = np.arange(4.0)
    direct = entry(scaled, numba.typeof(a), numba.float64)
    assert direct is not scaled and direct(a, 2.0) == scaled(a, 2.0) == 12.0
    assert len(scaled.signatures) == 1  # compiled once, for those types
