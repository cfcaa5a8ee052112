"""The restart checkpoint (pipeline/checkpoint.py, Journal.load_after): the accumulator's sums at
a journal position, loaded at start with only the journal's tail replayed, the same state as a
replay of the whole journal; a stale, corrupt or other-setup checkpoint is named and the journal
replayed whole."""

import json
import os

import numpy as np
import pytest

from rbc_registration.core.measurements.accumulator import FiducialAccumulator
from rbc_registration.core.measurements.pairing import StampPairer
from rbc_registration.core.measurements.records import Measurement
from rbc_registration.core.synthetic.cells import make_cell
from rbc_registration.core.synthetic.structure import moved_sessions
from rbc_registration.pipeline import checkpoint as cp
from rbc_registration.pipeline.ingest import Ingest
from rbc_registration.pipeline.journal import Journal

HEADER = {"working_frame": "tracker", "destination_frame": "world", "dimension": 2}


class Log:
    def __init__(self):
        self.lines = []

    def warning(self, line):
        self.lines.append(line)

    info = error = warning


def _acc(**kwargs) -> FiducialAccumulator:
    return FiducialAccumulator(2, "tracker", "world", merge_radius=1.0, **kwargs)


def _records() -> list:
    """A two-session stream with a bump nobody declared (auto-1), a group, an enable change,
    auto ids, repeated stamps (the duplicate window) and a fiducial re-measured."""
    cell = moved_sessions(make_cell("RA", 1, repeats=1), 1, 3.0)
    acc = _acc()
    out = []
    for k, fid in enumerate(cell.ids):
        out.append(acc.prepare(fid, cell.working[k], cell.destination[k], stamp_s=100.0 + k,
                               group="g0" if fid == cell.ids[0] else ""))
        acc.commit(out[-1])
        if k == 5:
            out.append(acc.prepare_enabled(fid, False))
            acc.commit(out[-1])
    for k in range(3):
        out.append(acc.prepare(None, [50.0 + k, 50.0], [50.0 + k, 50.0], stamp_s=1.0))
        acc.commit(out[-1])
    return out


def _everything(acc: FiducialAccumulator) -> tuple:
    """Every stored value of ``acc``, for comparisons."""
    sums = acc.sessions
    return (acc.state_digest(), acc.session_digest(), acc._next_auto, acc.n_measurements,
            tuple((f, tuple(r.items())) for f, r in acc._recent.items()),
            tuple(acc._first_stamps.items()), acc._dest_means.tolist(),
            tuple((q, f, m.tolist(), p.tolist()) for q, f, m, p in sums._detector._recent),
            tuple((s, b.start, b.motion.rotation.tolist(), b.motion.translation.tolist(),
                   b.motion.fre_rms, b.p_value, b.n_fiducials) for s, b in sums.bumps),
            tuple(sums._starts.items()))


def _replayed(records, **kwargs) -> FiducialAccumulator:
    acc = _acc(**kwargs)
    assert acc.restore(records) == []
    return acc


def test_the_checkpoint_knows_every_field_of_the_accumulator():
    """A field added to the accumulator, its session sums or bump detector must be added to
    export_state / import_state too (then to this list)."""
    acc = _acc()
    assert set(vars(acc)) == {
        "dimension", "working_frame", "destination_frame", "merge_radius", "outlier_distance",
        "max_stamp_age", "duplicate_window", "_fiducials", "_dest_means", "_order", "_index",
        "_next_auto", "_recent", "n_measurements", "rejected", "_groups", "_first_stamps",
        "sessions"}
    assert set(vars(acc.sessions)) == {"dimension", "tail", "_cells", "_starts", "current",
                                       "_tail", "_detector", "_sequence", "bumps"}
    assert set(vars(acc.sessions._detector)) == {"dimension", "window", "every", "significance",
                                                 "_recent", "_critical", "_tested"}


@pytest.mark.parametrize("split", [0, 1, 7, 20, -4, -1])
def test_sums_at_a_split_then_the_tail_equal_a_whole_replay(split):
    records = _records()
    whole = _replayed(records)
    assert whole.sessions.bumps and "auto-1" in whole.sessions.names
    head = _replayed(records[:split] if split else [])
    text = cp.checkpoint_text(head, {"t": "h", "version": 2, **HEADER},
                              cp.JournalPosition(0, 0, 0, 0, 0))
    loaded = _acc()
    cp.import_state(loaded, json.loads(text.split("\n", 1)[1])["state"])
    assert _everything(loaded) == _everything(head)
    assert cp.replay(loaded, records[split:] if split else records) == []
    assert _everything(loaded) == _everything(whole)
    a, b = loaded.fiducial_set(), whole.fiducial_set()
    assert a.ids == b.ids and a.groups == b.groups and a.disabled_ids == b.disabled_ids
    np.testing.assert_array_equal(a.working, b.working)
    np.testing.assert_array_equal(a.repeat_stats.variances, b.repeat_stats.variances)


def _ingest(tmp_path, log=None, **kwargs):
    acc = _acc(**kwargs)
    journal = Journal(str(tmp_path), HEADER)
    return Ingest(acc, StampPairer(0.01, 8), journal, log or Log()), acc, journal


def _live(tmp_path, records, at):
    """A live ingest that accepted ``records``, checkpointed after ``at`` of them."""
    ingest, acc, journal = _ingest(tmp_path)
    ingest.restore()
    for k, record in enumerate(records):
        if k == at:
            (tmp_path / cp.CHECKPOINT_NAME).write_text(ingest.checkpoint_text())
        assert ingest._accept(record)
    ingest.close()
    return acc


def _restart(tmp_path, **kwargs):
    log = Log()
    ingest, acc, journal = _ingest(tmp_path, log, **kwargs)
    calls = []
    load_after = journal.load_after
    journal.load_after = lambda position: calls.append(position) or load_after(position)
    restored = ingest.restore()
    return ingest, acc, journal, log, restored, calls


def test_a_restart_loads_the_checkpoint_and_replays_only_the_tail(tmp_path):
    records = _records()
    live = _live(tmp_path, records, at=len(records) - 5)
    ingest, acc, journal, log, restored, calls = _restart(tmp_path)
    assert log.lines == [] and len(calls) == 1
    assert restored == live.n_measurements
    assert _everything(acc) == _everything(live)
    # the journal is open after its last record: appends go on, a whole load sees them
    extra = Measurement("late", (9.0, 9.0), (9.0, 9.0), 500.0)
    assert ingest._accept(extra)
    tail_pos = journal.position()
    ingest.close()
    whole = Journal(str(tmp_path), HEADER)
    loaded, warnings = whole.load()
    assert loaded == [*records, extra] and warnings == []
    assert whole.position() == tail_pos
    whole.close()


def test_the_position_after_a_load_is_the_position_written_live(tmp_path):
    records = _records()
    ingest, _acc_live, journal = _ingest(tmp_path)
    ingest.restore()
    for record in records:
        assert ingest._accept(record)
    live = journal.position()
    ingest.close()
    again = Journal(str(tmp_path), HEADER)
    again.load()
    assert again.position() == live
    data = (tmp_path / "journal.jsonl").read_bytes()
    assert live.offset == len(data) and live.lines == data.count(b"\n")
    assert live.records == len(records)
    again.close()


def test_a_stale_checkpoint_is_named_and_the_journal_replayed_whole(tmp_path):
    records = _records()
    _live(tmp_path, records, at=10)
    # the journal rewritten with other records of the same length: same size, other bytes
    path = tmp_path / "journal.jsonl"
    lines = path.read_bytes().split(b"\n")
    lines[3], lines[4] = lines[4], lines[3]
    path.write_bytes(b"\n".join(lines))
    ingest, acc, journal, log, restored, calls = _restart(tmp_path)
    assert len(calls) == 1
    assert any("does not match the journal" in line and "replayed whole" in line
               for line in log.lines), log.lines
    want = _replayed(Journal(str(tmp_path), HEADER).load()[0])
    assert _everything(acc) == _everything(want)


def test_a_journal_shorter_than_the_checkpoint_is_replayed_whole(tmp_path):
    records = _records()
    _live(tmp_path, records, at=len(records) - 1)
    path = tmp_path / "journal.jsonl"
    data = path.read_bytes()
    path.write_bytes(data[:data.index(b"\n") + 1])     # only the header left
    ingest, acc, journal, log, restored, calls = _restart(tmp_path)
    assert restored == 0 and any("fewer than the checkpoint's" in line for line in log.lines)


def test_a_corrupt_checkpoint_is_named_and_the_journal_replayed_whole(tmp_path):
    records = _records()
    live = _live(tmp_path, records, at=12)
    path = tmp_path / cp.CHECKPOINT_NAME
    text = path.read_text()
    k = text.index('"n_measurements":') + len('"n_measurements":')
    path.write_text(text[:k] + ("9" if text[k] != "9" else "8") + text[k + 1:])
    ingest, acc, journal, log, restored, calls = _restart(tmp_path)
    assert calls == [] and any("is corrupt" in line and "replayed whole" in line
                               for line in log.lines), log.lines
    assert _everything(acc) == _everything(live)


@pytest.mark.parametrize("content", [b"", b"not json\n", b"00000000\n{}\n"])
def test_an_unreadable_checkpoint_is_named_and_the_journal_replayed_whole(tmp_path, content):
    records = _records()
    live = _live(tmp_path, records, at=12)
    (tmp_path / cp.CHECKPOINT_NAME).write_bytes(content)
    ingest, acc, journal, log, restored, calls = _restart(tmp_path)
    assert calls == [] and len(log.lines) == 1 and "replayed whole" in log.lines[0]
    assert _everything(acc) == _everything(live)


def test_a_checkpoint_of_other_settings_is_named_and_the_journal_replayed_whole(tmp_path):
    records = _records()
    _live(tmp_path, records, at=12)
    ingest, acc, journal, log, restored, calls = _restart(tmp_path, duplicate_window=4)
    assert calls == []
    assert any("another setup: duplicate_window 16 (now 4)" in line for line in log.lines), \
        log.lines
    assert _everything(acc) == _everything(_replayed(records, duplicate_window=4))


def test_skipped_lines_count_the_same_as_a_whole_replay(tmp_path):
    records = _records()
    _live(tmp_path, records, at=len(records) - 2)
    path = tmp_path / "journal.jsonl"
    data = bytearray(path.read_bytes())
    data[data.index(b'"w":[') + 6] ^= 1       # a digit of the first record: its CRC fails
    path.write_bytes(bytes(data))
    ingest, _, _, log, _, _ = _restart(tmp_path)
    assert any("does not match the journal" in line for line in log.lines)
    assert ingest.n_replay_skipped == 1
    # that state checkpointed (the skipped line in it), then a tail: the same count again
    (tmp_path / cp.CHECKPOINT_NAME).write_text(ingest.checkpoint_text())
    assert ingest._accept(Measurement("late", (9.0, 9.0), (9.0, 9.0), 500.0))
    ingest.close()
    resumed, acc, _, log, _, calls = _restart(tmp_path)
    assert len(calls) == 1 and resumed.n_replay_skipped == 1
    assert [line.split(";")[0] for line in log.lines] == ["journal replay skipped 1 record(s)"]
    resumed.close()
    os.makedirs(tmp_path / "copy")
    (tmp_path / "copy" / "journal.jsonl").write_bytes(path.read_bytes())
    whole, whole_acc, _ = _ingest(tmp_path / "copy")
    whole.restore()
    assert whole.n_replay_skipped == 1
    assert _everything(acc) == _everything(whole_acc)


def test_a_torn_tail_after_the_checkpoint_is_cut_off(tmp_path):
    records = _records()
    live = _live(tmp_path, records, at=len(records) - 3)
    path = tmp_path / "journal.jsonl"
    with open(path, "ab") as f:
        f.write(b'{"t":"m","id":"torn","w":[1.0,')
    ingest, acc, journal, log, restored, calls = _restart(tmp_path)
    assert len(calls) == 1 and any("torn last record" in line for line in log.lines)
    assert _everything(acc) == _everything(live)
    assert ingest._accept(Measurement("after", (7.0, 7.0), (7.0, 7.0), 600.0))
    ingest.close()
    loaded, warnings = Journal(str(tmp_path), HEADER).load()
    assert loaded[-1].fiducial_id == "after" and warnings == []


def test_reset_archives_the_checkpoint_with_the_journal(tmp_path):
    records = _records()
    _live(tmp_path, records, at=4)
    ingest, acc, journal, log, restored, calls = _restart(tmp_path)
    ok, _message = ingest.reset()
    assert ok and not (tmp_path / cp.CHECKPOINT_NAME).exists()
    assert [n for n in os.listdir(tmp_path) if n.startswith(cp.CHECKPOINT_NAME + ".")]
    assert journal.position().records == 0
    ingest.close()
