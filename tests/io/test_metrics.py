"""The learning-curve CSV: its resume-time rewrite is atomic, and a row cut short by a kill is never kept."""

import csv
import os

import pytest

from pedrl.io import CsvWriter, read_csv

COLUMNS = ("trial", "global_trial", "value")


def _write(path, rows):
    writer = CsvWriter(path, COLUMNS)
    for row in rows:
        writer.write(row)
    writer.close()


def _rows(count):
    return [{"trial": i, "global_trial": i, "value": 0.5 * i} for i in range(count)]


def test_resume_keeps_the_rows_before_the_checkpoint(tmp_path):
    path = tmp_path / "learning_curve.csv"
    _write(path, _rows(6))
    writer = CsvWriter(path, COLUMNS, keep_rows=lambda row: int(row["global_trial"]) < 4)
    writer.write({"trial": 4, "global_trial": 4, "value": 9.0})
    writer.close()
    assert [r["global_trial"] for r in read_csv(path)] == ["0", "1", "2", "3", "4"]
    assert read_csv(path)[-1]["value"] == "9"
    assert sorted(os.listdir(tmp_path)) == ["learning_curve.csv"]


def test_an_interrupted_rewrite_leaves_every_row(tmp_path, monkeypatch):
    """A kill while the kept rows are rewritten used to leave a truncated file: the rows were lost for good."""
    path = tmp_path / "learning_curve.csv"
    _write(path, _rows(90))
    before = path.read_text()
    original = csv.DictWriter.writerow
    calls = {"n": 0}

    def interrupted(self, row):
        calls["n"] += 1
        if calls["n"] == 30:
            raise KeyboardInterrupt  # the kill arrives in the middle of the rewrite
        return original(self, row)

    monkeypatch.setattr(csv.DictWriter, "writerow", interrupted)
    with pytest.raises(KeyboardInterrupt):
        CsvWriter(path, COLUMNS, keep_rows=lambda row: int(row["global_trial"]) < 80)
    assert path.read_text() == before
    assert os.listdir(tmp_path) == ["learning_curve.csv"]


def test_a_row_cut_short_by_a_kill_is_dropped(tmp_path):
    path = tmp_path / "learning_curve.csv"
    _write(path, _rows(3))
    with open(path, "a") as handle:
        handle.write("3,1")  # global_trial "1" of "15", cut short: it must not count as trial 1
    writer = CsvWriter(path, COLUMNS, keep_rows=lambda row: int(row["global_trial"]) < 10)
    writer.close()
    assert [r["global_trial"] for r in read_csv(path)] == ["0", "1", "2"]


def test_a_temporary_left_by_a_kill_is_removed(tmp_path):
    path = tmp_path / "learning_curve.csv"
    _write(path, _rows(2))
    (tmp_path / ".learning_curve.csv.0badc0de.tmp").write_text("trial,glo")
    CsvWriter(path, COLUMNS, keep_rows=lambda row: True).close()
    assert os.listdir(tmp_path) == ["learning_curve.csv"]
    assert len(read_csv(path)) == 2


def test_a_full_disk_names_the_table(tmp_path):
    """A row flushed on a full disk fails with ENOSPC and no file name: the error names the table, so that the line a
    user sees says which file could not be written (it said "cannot use '?'")."""
    import errno

    from pedrl.cli import describe_os_error

    writer = CsvWriter(tmp_path / "scaling.csv", ["a"])

    class Full:
        closed = False

        def write(self, text: str = "") -> None:
            raise OSError(errno.ENOSPC, "No space left on device")

        flush = close = write

    writer._handle.close()
    writer._handle = Full()
    writer._writer = csv.DictWriter(writer._handle, fieldnames=["a"])
    with pytest.raises(OSError) as raised:
        writer.write({"a": 1})
    assert describe_os_error(raised.value) == f"cannot use {str(tmp_path / 'scaling.csv')!r}: No space left on device"
    with pytest.raises(OSError) as raised:
        writer.close()
    assert raised.value.filename == str(tmp_path / "scaling.csv")
