"""runtime.files: a loader that reads a file once while it is unchanged."""

import os

import pytest

from mjkin.runtime import files


def test_a_file_is_read_once_while_unchanged_and_again_after_an_edit(tmp_path):
    reads = []

    @files.per_file(maxsize=2)
    def load(path: str) -> str:
        reads.append(path)
        return open(path).read()

    f = tmp_path / "a.txt"
    f.write_text("one")
    assert load(f) == "one" and load(str(f)) == "one" and load(tmp_path / "." / "a.txt") == "one"
    assert reads == [str(f.resolve())]  # one read for every spelling of the path
    f.write_text("three")  # another size
    assert load(f) == "three"
    st = f.stat()
    f.write_text("four!")  # the same size: the modification time tells
    os.utime(f, ns=(st.st_atime_ns, st.st_mtime_ns + 1_000_000))
    assert load(f) == "four!" and len(reads) == 3
    with pytest.raises(FileNotFoundError):
        load(tmp_path / "missing.txt")
