"""issue 11: the journal's content is input. Each test failed on the code before the fix
(journal version 1: no checksums, no bounds, replay without the live validation, files opened
however they were)."""

import json
import os
import stat
import subprocess
import sys

import pytest

from rbc_registration.core.measurements.accumulator import FiducialAccumulator, Measurement
from rbc_registration.pipeline.journal import JOURNAL_NAME, Journal, JournalMismatch

HEADER = {"working_frame": "tracker", "destination_frame": "world", "dimension": 3}
GOOD = [Measurement(f"H{k}", (0.1 * k, 0.2, 0.3), (1.0 + 0.1 * k, 2.0, 3.0), 10.0 + k)
        for k in range(4)]


def write_v1(tmp_path, lines):
    """A version 1 journal (the old format: no checksums) with ``lines`` after the header."""
    head = json.dumps({"t": "h", "version": 1, **HEADER})
    (tmp_path / JOURNAL_NAME).write_text("\n".join([head, *lines]) + "\n")


def v1_line(record):
    return json.dumps({"t": "m", "id": record.fiducial_id, "w": list(record.working),
                       "d": list(record.destination), "s": record.stamp_s},
                      separators=(",", ":"))


def replay(tmp_path, header=HEADER):
    """Load + replay as the node does: (accumulator, number of skipped lines/records)."""
    journal = Journal(str(tmp_path), header)
    records, warnings = journal.load()
    journal.close()
    acc = FiducialAccumulator(header["dimension"], "tracker", "world", 0.01, 0.0)
    errors = acc.restore(records)
    skipped = [w for w in warnings if "record skipped" in w or "torn last" in w]
    return acc, len(skipped) + len(errors)


@pytest.mark.parametrize("bad", [
    '{"t":"m","id":"X","w":[' + "9" * 4000 + ',0,0],"d":[0,0,0],"s":1}',   # huge integer
    "[" * 100_000 + "]" * 100_000,                                          # deep nesting
    '{"t":"m","id":"X","w":[[[[[[1]]]]]],"d":[0,0,0],"s":1}',               # nested coordinate
    '{"t":"m","id":"X","w":[1,2,3],"d":[0,0,0],"s":' + "1" * 5000 + "}",   # huge stamp
], ids=["huge-int", "deep-nesting", "nested-coordinate", "huge-stamp"])
def test_a_hostile_line_is_skipped_and_the_rest_replayed(tmp_path, bad):
    write_v1(tmp_path, [v1_line(GOOD[0]), bad, v1_line(GOOD[1])])
    acc, skipped = replay(tmp_path)          # before: OverflowError / RecursionError
    assert acc.n_measurements == 2 and skipped == 1


@pytest.mark.parametrize("value", ["NaN", "Infinity", "-Infinity", "1e300", "true"])
def test_replay_applies_the_live_validation(tmp_path, value):
    bad = '{"t":"m","id":"X","w":[0.5,' + value + ',0.5],"d":[1,2,3],"s":5}'
    write_v1(tmp_path, [v1_line(GOOD[0]), bad, v1_line(GOOD[1])])
    acc, skipped = replay(tmp_path)          # before: accepted, the model invalid forever
    assert acc.n_measurements == 2 and skipped == 1
    assert "X" not in acc.ids
    if value != "true":   # the live path refuses the same values (one check, check_record)
        live = FiducialAccumulator(3, "tracker", "world", 0.01, 0.0)
        with pytest.raises(ValueError):
            live.prepare("X", [0.5, json.loads(value), 0.5], [1, 2, 3])


@pytest.mark.parametrize("bad", ['{"t":"e","id":"H0","on":"yes"}', '{"t":"m","id":7,"w":[1,2,3],'
                                 '"d":[1,2,3],"s":1}', '{"t":"m","id":"","w":[1,2,3],'
                                 '"d":[1,2,3],"s":1}', '{"t":"m","id":"a\\nb","w":[1,2,3],'
                                 '"d":[1,2,3],"s":1}'],
                         ids=["string-flag", "integer-id", "empty-id", "id-with-line-break"])
def test_records_of_the_wrong_types_are_skipped(tmp_path, bad):
    write_v1(tmp_path, [v1_line(GOOD[0]), bad])
    acc, skipped = replay(tmp_path)
    assert acc.n_measurements == 1 and skipped == 1 and acc.is_enabled("H0")


def write_good(state_dir):
    """A version 2 journal of the GOOD records in ``state_dir``; returns its path."""
    j = Journal(str(state_dir), HEADER)
    j.load()
    for r in GOOD:
        j.append(r)
    j.close()
    return state_dir / JOURNAL_NAME


def test_a_flipped_digit_is_detected(tmp_path):
    path = write_good(tmp_path)
    lines = path.read_bytes().split(b"\n")
    assert b"1.2" in lines[3]
    lines[3] = lines[3].replace(b"1.2", b"1.3", 1)        # one digit of GOOD[2]'s destination
    path.write_bytes(b"\n".join(lines))
    acc, skipped = replay(tmp_path)          # before: restored silently with the wrong value
    assert skipped == 1 and acc.ids == ("H0", "H1", "H3")


@pytest.mark.parametrize("other", [{"dimension": 2}, {"working_frame": "camera"},
                                   {"destination_frame": "map"}])
def test_a_headerless_journal_of_another_setup_is_refused(tmp_path, other):
    path = write_good(tmp_path)
    path.write_bytes(b"\n".join(path.read_bytes().split(b"\n")[1:]))   # the header line lost
    with pytest.raises(JournalMismatch, match="no header line"):   # before: restored
        Journal(str(tmp_path), {**HEADER, **other}).load()
    acc, skipped = replay(tmp_path)          # the same setup still reads its own records
    assert acc.n_measurements == len(GOOD) and skipped == 0


def test_a_journal_of_an_unknown_version_is_refused(tmp_path):
    (tmp_path / JOURNAL_NAME).write_text(json.dumps({"t": "h", "version": 99, **HEADER}) + "\n")
    with pytest.raises(JournalMismatch, match="version 99"):
        Journal(str(tmp_path), HEADER).load()


# -- files that are not what they seem ---------------------------------------------------------
def test_a_symlinked_journal_is_refused_and_its_target_untouched(tmp_path):
    victim = tmp_path / "victim.txt"
    victim.write_text("precious\n" * 10)
    state = tmp_path / "state"
    state.mkdir()
    os.symlink(victim, state / JOURNAL_NAME)
    with pytest.raises(ValueError, match="is a symlink, not a regular file"):
        Journal(str(state), HEADER).load()   # before: victim truncated and appended to
    assert victim.read_text() == "precious\n" * 10


def test_dev_zero_a_directory_and_a_fifo_are_refused(tmp_path):
    for k, make in enumerate((lambda p: os.symlink("/dev/zero", p), os.mkdir, os.mkfifo)):
        state = tmp_path / f"s{k}"
        state.mkdir()
        make(state / JOURNAL_NAME)
        # In a child process with a timeout: before the fix a FIFO hung the open forever and
        # /dev/zero was read until memory ran out.
        code = ("import sys; from rbc_registration.pipeline.journal import Journal\n"
                "try:\n    Journal(sys.argv[1], {'working_frame': 'tracker', "
                "'destination_frame': 'world', 'dimension': 3}).load()\n"
                "except ValueError as e:\n    print(e); sys.exit(3)\n")
        proc = subprocess.run([sys.executable, "-c", code, str(state)], capture_output=True,
                              text=True, timeout=20)
        assert proc.returncode == 3, proc.stderr[-500:]
        assert "not a regular file" in proc.stdout and str(state) in proc.stdout


@pytest.mark.parametrize("umask", [0o000, 0o022, 0o277])
def test_files_are_0600_and_directories_0700_whatever_the_umask(tmp_path, umask):
    old = os.umask(umask)
    try:
        j = Journal(str(tmp_path / "new" / "state"), HEADER)
        j.load()
        j.append(GOOD[0])
        j.close()
    finally:
        os.umask(old)
    state = tmp_path / "new" / "state"
    assert stat.S_IMODE(os.stat(state).st_mode) == 0o700
    assert stat.S_IMODE(os.stat(state / JOURNAL_NAME).st_mode) == 0o600
