"""Journal and snapshot of registration_node (pure: no rclpy)."""

import json
import os

import pytest

from rbc_registration.core.accumulator import EnabledChange, FiducialAccumulator, Measurement
from rbc_registration.ros.persistence import (JOURNAL_NAME, Journal, JournalMismatch,
                                              record_from_json, record_to_json, write_atomic)

HEADER = {"working_frame": "tracker", "destination_frame": "world", "dimension": 3}


def records():
    return [Measurement("H1", (0.1, 0.2, 0.30000000000000004), (1.0, 2.0, 3.0), 12.5),
            Measurement("auto-0000", (1e-17, -2.5, 3.0), (4.0, 5.0, 6.0), 13.0, auto_id=True),
            EnabledChange("H1", False)]


def test_records_round_trip_bit_exact():
    for record in records():
        assert record_from_json(record_to_json(record)) == record


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


def test_torn_last_line_is_skipped_with_a_warning_and_cut_off(tmp_path):
    j = Journal(str(tmp_path), HEADER)
    j.load()
    for r in records()[:2]:
        j.append(r)
    j.close()
    path = tmp_path / JOURNAL_NAME
    with open(path, "ab") as f:
        f.write(b'{"t":"m","id":"H9","w":[0.1,0.2')   # a write cut short by SIGKILL
    j2 = Journal(str(tmp_path), HEADER)
    loaded, warnings = j2.load()
    assert loaded == records()[:2]
    assert len(warnings) == 1 and "torn last record" in warnings[0]
    j2.append(records()[2])          # appends start on a fresh line
    j2.close()
    assert Journal(str(tmp_path), HEADER).load() == (records(), [])


def test_corrupt_middle_line_is_skipped(tmp_path):
    path = tmp_path / JOURNAL_NAME
    lines = [json.dumps({"t": "h", "version": 1, **HEADER}), record_to_json(records()[0]),
             "garbage{", record_to_json(records()[1])]
    path.write_text("\n".join(lines) + "\n")
    loaded, warnings = Journal(str(tmp_path), HEADER).load()
    assert loaded == records()[:2]
    assert len(warnings) == 1 and ":3: unreadable record skipped" in warnings[0]


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
