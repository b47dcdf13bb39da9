"""The numba cache guard: caches go when any source changes, and only then."""

from mjkin.jit import drop_stale_caches


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
