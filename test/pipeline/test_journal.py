"""Journal and snapshot of registration_node (pure: no rclpy)."""

import errno
import json
import os
import subprocess
import sys

import numpy as np
import pytest

from rbc_registration.core.measurements.accumulator import (EnabledChange, FiducialAccumulator,
                                                            Measurement)
from rbc_registration.pipeline.journal import (JOURNAL_NAME, Journal, JournalMismatch,
                                               record_from_json, record_to_json)
from rbc_registration.pipeline.snapshot import write_atomic

HEADER = {"working_frame": "tracker", "destination_frame": "world", "dimension": 3}


def records():
    return [Measurement("H1", (0.1, 0.2, 0.30000000000000004), (1.0, 2.0, 3.0), 12.5),
            Measurement("auto-0000", (1e-17, -2.5, 3.0), (4.0, 5.0, 6.0), 13.0, auto_id=True),
            EnabledChange("H1", False)]


def test_records_round_trip_bit_exact():
    for record in records():
        assert record_from_json(record_to_json(record)) == record


def json_dumps_line(record):
    """The journal line as json.dumps wrote it before the direct encoding."""
    if isinstance(record, Measurement):
        obj = {"t": "m", "id": record.fiducial_id, "w": list(record.working),
               "d": list(record.destination), "s": record.stamp_s}
        if record.auto_id:
            obj["auto"] = True
    else:
        obj = {"t": "e", "id": record.fiducial_id, "on": record.enabled}
    return json.dumps(obj, separators=(",", ":"), allow_nan=False)


@pytest.mark.parametrize("seed", range(4))
def test_direct_encoding_is_what_json_dumps_gave(seed):
    """Every character as before (ids with quotes, backslashes, control and non-ASCII
    characters; subnormal, signed-zero, huge and integral floats), and bit-exact back."""
    rng = np.random.default_rng(seed)
    ids = ["H1", 'a"b', "back\\slash", "tab\tx", "wörld-ß", "\u2603\U0001F600", "", "x" * 256,
           "\x7f\x01"]
    specials = [0.0, -0.0, 5e-324, 1e-310, 1.7976931348623157e308, -1e150, 3.0, 1e16, 0.1]
    for k in range(300):
        d = (2, 3)[k % 2]
        pick = [specials[i] for i in rng.integers(0, len(specials), 2 * d + 1)]
        values = [float(v) for v in rng.normal(scale=10.0 ** rng.integers(-20, 20), size=2 * d + 1)]
        vals = pick if k % 3 == 0 else values
        record = Measurement(ids[k % len(ids)], tuple(vals[:d]), tuple(vals[d:2 * d]), vals[-1],
                             bool(k % 5 == 0))
        line = record_to_json(record)
        assert line == json_dumps_line(record)
        assert record_from_json(line) == record
    for record in records():
        assert record_to_json(record) == json_dumps_line(record)


@pytest.mark.parametrize("bad", [float("nan"), float("inf"), -float("inf")])
def test_a_nonfinite_coordinate_is_still_refused(bad):
    with pytest.raises(ValueError):
        record_to_json(Measurement("H1", (bad, 0.0, 0.0), (0.0, 0.0, 0.0), 1.0))


def test_non_float_values_take_the_json_path():
    record = Measurement("H1", (1, 2, 3), (np.float64(0.5), 0.0, 0.0), 2)
    assert record_to_json(record) == json_dumps_line(record)


@pytest.mark.parametrize("line, match", [
    ('{"t":"x"}', "unknown journal record type"),
    ('[1,2]', "must be a JSON object"),
    ('{"t":"m","id":"a","w":["x",0,0],"d":[0,0,0],"s":0}', "coordinates must be numbers"),
])
def test_bad_lines_raise_value_error(line, match):
    with pytest.raises(ValueError, match=match):
        record_from_json(line)


def test_append_then_load_gives_the_same_records(tmp_path):
    j = Journal(str(tmp_path), HEADER)
    assert j.load() == ([], [])
    for r in records():
        j.append(r)
    j.close()
    # Written and flushed per record: readable without closing too.
    loaded, warnings = Journal(str(tmp_path), HEADER).load()
    assert loaded == records() and warnings == []
    first = (tmp_path / JOURNAL_NAME).read_text().splitlines()[0]
    assert json.loads(first)["t"] == "h"


def journal_of_two(tmp_path):
    """A closed journal of the first two records; its path."""
    j = Journal(str(tmp_path), HEADER)
    j.load()
    for r in records()[:2]:
        j.append(r)
    j.close()
    return tmp_path / JOURNAL_NAME


def test_torn_last_line_is_skipped_with_a_warning_and_cut_off(tmp_path):
    path = journal_of_two(tmp_path)
    with open(path, "ab") as f:
        f.write(b'{"t":"m","id":"H9","w":[0.1,0.2')   # a write cut short by SIGKILL
    j2 = Journal(str(tmp_path), HEADER)
    loaded, warnings = j2.load()
    assert loaded == records()[:2]
    assert len(warnings) == 1 and "torn last record" in warnings[0]
    j2.append(records()[2])          # appends start on a fresh line
    j2.close()
    assert Journal(str(tmp_path), HEADER).load() == (records(), [])


def test_a_whole_last_record_without_its_newline_is_kept(tmp_path):
    """a journal whose final newline was lost (a hand edit, `printf %s "$(cat ...)"`)
    had its last, valid record deleted from disk as torn."""
    path = journal_of_two(tmp_path)
    path.write_bytes(path.read_bytes()[:-1])
    j2 = Journal(str(tmp_path), HEADER)
    loaded, warnings = j2.load()
    assert loaded == records()[:2] and j2.n_skipped == 0
    assert len(warnings) == 1 and "last record without a newline kept (its checksum holds)" in \
        warnings[0]
    assert path.read_bytes().endswith(b"\n")
    j2.append(records()[2])
    j2.close()
    assert Journal(str(tmp_path), HEADER).load() == (records(), [])


def test_a_kept_last_record_whose_newline_cannot_be_written_is_cut_off(tmp_path, monkeypatch):
    path = journal_of_two(tmp_path)
    whole = path.read_bytes()
    path.write_bytes(whole[:-1])
    j = Journal(str(tmp_path), HEADER)

    def refuse(data):
        raise OSError(errno.ENOSPC, "no space left")
    monkeypatch.setattr(j, "_write", refuse)
    loaded, warnings = j.load()
    assert loaded == records()[:1]
    assert len(warnings) == 1 and "last record without a newline skipped: the newline could not " \
        "be added" in warnings[0]
    assert path.read_bytes() == whole[:whole.rstrip(b"\n").rfind(b"\n") + 1]   # one whole line
    j.close()


def test_corrupt_middle_line_is_skipped(tmp_path):
    j = Journal(str(tmp_path), HEADER)
    j.load()
    j.append(records()[0])
    os.write(j._fd, b"garbage{\n")
    j.append(records()[1])
    j.close()
    loaded, warnings = Journal(str(tmp_path), HEADER).load()
    assert loaded == records()[:2]
    assert len(warnings) == 1 and ":3: unreadable record skipped" in warnings[0]


def test_a_version_1_journal_is_read_and_rewritten_as_version_2(tmp_path):
    path = tmp_path / JOURNAL_NAME
    lines = [json.dumps({"t": "h", "version": 1, **HEADER}), record_to_json(records()[0]),
             "garbage{", record_to_json(records()[1])]
    path.write_text("\n".join(lines) + "\n")
    loaded, warnings = Journal(str(tmp_path), HEADER).load()
    assert loaded == records()[:2]
    assert ":3: unreadable record skipped" in warnings[0]
    assert "journal version 1 rewritten as version 2" in warnings[1]
    assert json.loads(path.read_text().splitlines()[0])["version"] == 2
    assert Journal(str(tmp_path), HEADER).load() == (records()[:2], [])
    assert any(".v1." in name for name in os.listdir(tmp_path))


def test_a_journal_of_another_setup_is_refused(tmp_path):
    j = Journal(str(tmp_path), HEADER)
    j.load()
    j.close()
    with pytest.raises(JournalMismatch, match="dimension=3.*dimension=2"):
        Journal(str(tmp_path), {**HEADER, "dimension": 2}).load()


def test_archive_starts_a_new_journal(tmp_path):
    j = Journal(str(tmp_path), HEADER)
    j.load()
    j.append(records()[0])
    (tmp_path / "calibration.json").write_text("{}")
    archived = j.archive()
    assert archived and os.path.exists(archived)
    assert not (tmp_path / "calibration.json").exists()
    j.append(records()[1])
    j.close()
    assert Journal(str(tmp_path), HEADER).load()[0] == [records()[1]]


def test_replaying_a_journal_rebuilds_the_accumulator(tmp_path):
    acc = FiducialAccumulator(3, "tracker", "world", 0.01, 0.0)
    j = Journal(str(tmp_path), HEADER)
    j.load()
    for k in range(10):
        rec = acc.prepare(None if k % 3 else f"H{k % 4}", [k * 0.1, 0, 0], [1 + k * 0.1, 0, 0])
        j.append(rec)
        acc.commit(rec)
    change = acc.prepare_enabled("H0", False)
    j.append(change)
    acc.commit(change)
    j.close()
    other = FiducialAccumulator(3, "tracker", "world", 0.5, 0.0)
    assert other.restore(Journal(str(tmp_path), HEADER).load()[0]) == []
    assert other.state_digest() == acc.state_digest()


def test_write_atomic_replaces_whole_file(tmp_path):
    path = str(tmp_path / "sub" / "calibration.json")
    write_atomic(path, "one")
    write_atomic(path, "two")
    assert open(path).read() == "two"
    assert os.listdir(tmp_path / "sub") == ["calibration.json"]


# -- write failures (disk full, file-size limit): nothing of a failed record stays -------------
def short_writes_then(error_no, fail_on):
    """A fake ``os.write``: call ``fail_on`` writes half of its data, the next call raises."""
    real = os.write
    calls = {"n": 0, "failing": False}

    def fake(fd, data):
        calls["n"] += 1
        if calls["failing"]:
            calls["failing"] = False
            raise OSError(error_no, os.strerror(error_no))
        if calls["n"] == fail_on:
            calls["failing"] = True
            return real(fd, bytes(data[:len(data) // 2]))
        return real(fd, data)
    return fake


def test_a_failed_write_is_cut_off_and_never_reappears(tmp_path, monkeypatch):
    j = Journal(str(tmp_path), HEADER)
    j.load()
    j.append(records()[0])
    size = os.path.getsize(tmp_path / JOURNAL_NAME)
    monkeypatch.setattr(os, "write", short_writes_then(errno.ENOSPC, fail_on=1))
    with pytest.raises(OSError, match="No space left"):
        j.append(records()[1])           # half of it was written, then the disk was full
    assert os.path.getsize(tmp_path / JOURNAL_NAME) == size   # cut off again at once
    monkeypatch.undo()
    j.append(records()[2])               # space again: the next record follows cleanly
    j.close()
    assert Journal(str(tmp_path), HEADER).load() == ([records()[0], records()[2]], [])


def test_a_failed_cut_off_is_repeated_before_the_next_record(tmp_path, monkeypatch):
    j = Journal(str(tmp_path), HEADER)
    j.load()
    monkeypatch.setattr(os, "write", short_writes_then(errno.EFBIG, fail_on=1))
    monkeypatch.setattr(os, "ftruncate", lambda fd, n: (_ for _ in ()).throw(OSError(errno.EIO,
                                                                                   "I/O error")))
    with pytest.raises(OSError, match="File too large"):
        j.append(records()[0])
    monkeypatch.undo()
    j.append(records()[1])
    j.close()
    assert Journal(str(tmp_path), HEADER).load() == ([records()[1]], [])


def test_a_new_journal_whose_header_cannot_be_written_yet(tmp_path, monkeypatch):
    j = Journal(str(tmp_path), HEADER)
    monkeypatch.setattr(os, "write", short_writes_then(errno.ENOSPC, fail_on=1))
    loaded, warnings = j.load()
    assert loaded == [] and len(warnings) == 1 and "header not written yet" in warnings[0]
    monkeypatch.undo()
    j.append(records()[0])               # the header goes first, with the record
    j.close()
    assert Journal(str(tmp_path), HEADER).load() == ([records()[0]], [])


FSIZE_WRITER = """
import resource, signal, sys
from rbc_registration.core.measurements.accumulator import Measurement
from rbc_registration.pipeline.journal import Journal
signal.signal(signal.SIGXFSZ, signal.SIG_IGN)       # writes beyond the limit fail with EFBIG
resource.setrlimit(resource.RLIMIT_FSIZE, (int(sys.argv[2]), int(sys.argv[2])))
j = Journal(sys.argv[1], {"working_frame": "tracker", "destination_frame": "world",
                          "dimension": 3})
j.load()
accepted = failed = 0
for k in range(200):
    try:
        j.append(Measurement(f"H{k}", (0.1 * k, 0.2, 0.3), (1.0, 2.0, 3.0), 100.0 + k))
        accepted += 1
    except OSError as exc:
        failed += 1
        error = exc
print(accepted, failed, error.errno)
"""


def test_a_real_file_size_limit_keeps_exactly_the_accepted_records(tmp_path):
    """RLIMIT_FSIZE in a child process: real EFBIG short writes, as on a full disk."""
    out = subprocess.run([sys.executable, "-c", FSIZE_WRITER, str(tmp_path), "4000"],
                         capture_output=True, text=True, check=True, timeout=60).stdout
    accepted, failed, error_no = map(int, out.split())
    assert 0 < accepted < 200 and accepted + failed == 200 and error_no == errno.EFBIG
    loaded, warnings = Journal(str(tmp_path), HEADER).load()
    assert warnings == [] and [r.fiducial_id for r in loaded] == [f"H{k}" for k in
                                                                  range(accepted)]


def test_a_failed_archive_leaves_the_journal_open_and_reset_forgets_nothing(tmp_path,
                                                                            monkeypatch):
    """~/reset with a journal that cannot be moved (an immutable state_dir): the
    journal was closed first and never reopened, so every later pair was dropped with an
    AssertionError no counter showed, and the memory (cleared) and the journal (kept)
    disagreed. Now nothing is forgotten and appends go on."""
    from rbc_registration.core.measurements.pairing import StampPairer
    from rbc_registration.pipeline.ingest import Ingest

    acc = FiducialAccumulator(3, "tracker", "world", 0.005, 0.0)
    journal = Journal(str(tmp_path), HEADER)
    journal.load()
    ingest = Ingest(acc, StampPairer(0.02), journal, logger=None)
    rec = acc.prepare("H1", [0.1, 0.2, 0.3], [1.0, 2.0, 3.0])
    journal.append(rec)
    acc.commit(rec)
    real_replace = os.replace

    def refuse(src, dst):
        raise PermissionError(errno.EPERM, "Operation not permitted", src)

    monkeypatch.setattr(os, "replace", refuse)
    ok, message = ingest.reset()
    assert not ok and message.startswith(
        "nothing forgotten: archiving the journal (and snapshot) failed")
    assert acc.fiducial_set().ids == ("H1",)
    monkeypatch.setattr(os, "replace", real_replace)
    journal.append(records()[1])                     # still open
    journal.close()
    assert Journal(str(tmp_path), HEADER).load()[0] == [rec, records()[1]]


def test_appending_to_a_closed_journal_is_an_os_error(tmp_path):
    j = Journal(str(tmp_path), HEADER)
    j.load()
    j.close()
    with pytest.raises(OSError, match="the journal is not open"):
        j.append(records()[0])


def test_an_archive_that_cannot_create_the_new_journal_puts_the_old_one_back(tmp_path,
                                                                            monkeypatch):
    """The journal was moved, then the new one could not be created (EMFILE): the old one was
    closed and left as .bak, so every later pair failed and a restart restored nothing."""
    from rbc_registration.pipeline import journal as jmod

    j = Journal(str(tmp_path), HEADER)
    j.load()
    j.append(records()[0])
    real = jmod.open_private

    def refuse(*args, **kwargs):
        raise OSError(errno.EMFILE, "Too many open files")

    monkeypatch.setattr(jmod, "open_private", refuse)
    with pytest.raises(OSError, match="Too many open files"):
        j.archive()
    monkeypatch.setattr(jmod, "open_private", real)
    assert sorted(p.name for p in tmp_path.iterdir()) == [JOURNAL_NAME]
    j.append(records()[1])
    j.close()
    assert Journal(str(tmp_path), HEADER).load()[0] == records()[:2]
