"""files.write_atomic: the one way the package writes a file (run JSON, map, cloud, replay,
tables, records): the new content replaces the old whole, and a failed write leaves the old
content and no temporary file behind."""

import pytest

from nbvs_drake.files import write_atomic


def test_write_atomic_replaces_whole_and_leaves_no_temporary(tmp_path):
    p = tmp_path / "a" / "summary.json"
    with pytest.raises(FileNotFoundError):
        write_atomic(p, "{}")  # the folder is missing and mkdir was not asked
    assert write_atomic(p, '{"coverage": 0.9}', mkdir=True) == p
    assert p.read_text() == '{"coverage": 0.9}'
    write_atomic(str(p), b"\x00\x01")  # bytes, and a str path
    assert p.read_bytes() == b"\x00\x01"
    assert sorted(x.name for x in p.parent.iterdir()) == ["summary.json"]


def test_a_failed_write_keeps_the_old_content(tmp_path):
    p = tmp_path / "table.md"
    write_atomic(p, "old")
    with pytest.raises(TypeError):
        write_atomic(p, 12345)  # neither text nor bytes: fails while writing the temporary
    assert p.read_text() == "old"
    assert [x.name for x in tmp_path.iterdir()] == ["table.md"]
