"""The calibration snapshot of registration_node (pure: no rclpy): atomic writes, an interrupted
write (SIGKILL inside it, with a writer that pauses half way), and the start-up tidy-up that
never lets a partial or corrupt snapshot be used."""

import json
import os
import signal
import subprocess
import sys
import time

import pytest

from rbc_registration.pipeline import snapshot
from rbc_registration.pipeline.snapshot import (SNAPSHOT_FORMAT, SNAPSHOT_NAME, read_snapshot,
                                                tidy_state_dir, write_atomic)

PAUSED_WRITER = os.path.join(os.path.dirname(os.path.abspath(__file__)), "paused_writer.py")

GOOD = json.dumps({"format": SNAPSHOT_FORMAT, "n_measurements": 3})


def test_a_failed_write_keeps_the_old_snapshot_and_leaves_no_temporary_file(tmp_path,
                                                                            monkeypatch):
    path = str(tmp_path / SNAPSHOT_NAME)
    write_atomic(path, GOOD)

    def full_disk(fd):
        raise OSError(28, "No space left on device")
    monkeypatch.setattr(snapshot.os, "fsync", full_disk)
    with pytest.raises(OSError, match="No space left"):
        write_atomic(path, json.dumps({"format": SNAPSHOT_FORMAT, "n_measurements": 4}))
    assert os.listdir(tmp_path) == [SNAPSHOT_NAME]
    assert read_snapshot(path)["n_measurements"] == 3


@pytest.mark.parametrize("content, match", [
    pytest.param(GOOD[:len(GOOD) // 2], "not valid JSON", id="cut-short"),
    pytest.param("[1, 2]", "not a snapshot of format", id="other-json"),
    pytest.param(b"\xff\xfe", "not valid JSON", id="binary"),
])
def test_read_snapshot_refuses_a_partial_or_foreign_file(tmp_path, content, match):
    path = tmp_path / SNAPSHOT_NAME
    path.write_bytes(content if isinstance(content, bytes) else content.encode())
    with pytest.raises(ValueError, match=match):
        read_snapshot(str(path))


def test_tidy_removes_temporary_files_and_moves_a_corrupt_snapshot_aside(tmp_path):
    (tmp_path / f"{SNAPSHOT_NAME}.tmp.1234").write_text(GOOD[:10])
    (tmp_path / SNAPSHOT_NAME).write_text(GOOD[:-3])
    (tmp_path / "journal.jsonl").write_text("")
    warnings = tidy_state_dir(str(tmp_path))
    assert len(warnings) == 2
    assert "removed calibration.json.tmp.1234: a snapshot write was interrupted" in warnings[0]
    assert "is not a valid snapshot (not valid JSON" in warnings[1]
    assert "rebuilt from the journal" in warnings[1]
    names = sorted(os.listdir(tmp_path))
    assert names[0].startswith(f"{SNAPSHOT_NAME}.corrupt.") and names[1] == "journal.jsonl"
    assert len(names) == 2


def test_tidy_keeps_a_good_snapshot_and_accepts_a_missing_directory(tmp_path):
    (tmp_path / SNAPSHOT_NAME).write_text(GOOD)
    assert tidy_state_dir(str(tmp_path)) == []
    assert (tmp_path / SNAPSHOT_NAME).read_text() == GOOD
    assert tidy_state_dir(str(tmp_path / "nope")) == []


def test_sigkill_inside_a_write_leaves_the_old_snapshot_whole(tmp_path):
    """The writer pauses half way; SIGKILL lands inside the write, deterministically."""
    path = str(tmp_path / SNAPSHOT_NAME)
    write_atomic(path, GOOD)
    marker = tmp_path / "paused"
    new = json.dumps({"format": SNAPSHOT_FORMAT, "n_measurements": 4, "pad": "x" * 10000})
    proc = subprocess.Popen([sys.executable, PAUSED_WRITER, str(marker), path, new])
    try:
        end = time.monotonic() + 60
        while not marker.exists() and proc.poll() is None and time.monotonic() < end:
            time.sleep(0.01)
        assert marker.exists(), "the writer did not reach the hook"
        proc.send_signal(signal.SIGKILL)
        proc.wait(timeout=10)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    tmp = marker.read_text().strip()
    assert os.path.getsize(tmp) == len(new) // 2          # the half-written temporary file
    assert read_snapshot(path)["n_measurements"] == 3     # the snapshot itself is untouched
    warnings = tidy_state_dir(str(tmp_path))
    assert len(warnings) == 1 and "interrupted" in warnings[0] and not os.path.exists(tmp)
    assert read_snapshot(path)["n_measurements"] == 3


def test_parallel_writers_and_a_reader_never_fail_or_see_a_partial_file(tmp_path):
    """issue 11, severe 4: ``~/save`` and the recompute thread wrote the same temporary name
    (saves failed with ENOENT, readers saw invalid JSON). Four writers, a reader parsing
    continuously: 0 failures, 0 invalid reads, the final file is one writer's whole content."""
    import threading

    path = str(tmp_path / SNAPSHOT_NAME)
    write_atomic(path, GOOD)
    texts = {w: [json.dumps({"format": SNAPSHOT_FORMAT, "writer": w, "k": k,
                             "pad": "x" * (2000 + 997 * k % 5000)}) for k in range(40)]
             for w in range(4)}
    failures, invalid, reads = [], [], [0]
    done = threading.Event()

    def writer(w):
        for text in texts[w]:
            try:
                write_atomic(path, text)
            except OSError as exc:
                failures.append(exc)

    def reader():
        while not done.is_set():
            try:
                read_snapshot(path)
                reads[0] += 1
            except (ValueError, OSError) as exc:
                invalid.append(exc)

    threads = [threading.Thread(target=writer, args=(w,)) for w in texts]
    watcher = threading.Thread(target=reader)
    watcher.start()
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    done.set()
    watcher.join()
    assert failures == [] and invalid == [] and reads[0] > 0
    final = open(path).read()
    assert final in {text for w in texts for text in texts[w]}
    assert sorted(os.listdir(tmp_path)) == [SNAPSHOT_NAME]


def test_changed_settings_names_what_differs_from_the_last_snapshot(tmp_path):
    """Parameters set at runtime are not kept across a restart: the start says which."""
    from rbc_registration.pipeline.settings import Settings
    from rbc_registration.pipeline.snapshot import changed_settings

    start = Settings.from_mapping({"state_dir": str(tmp_path)})
    assert changed_settings(str(tmp_path), start) == ""                     # no snapshot
    runtime = start.replace(decision="off", outlier_distance=0.0)
    data = {"format": SNAPSHOT_FORMAT,
            "settings": {k: getattr(runtime, k) for k in runtime.__dataclass_fields__}}
    (tmp_path / SNAPSHOT_NAME).write_text(json.dumps(data))
    line = changed_settings(str(tmp_path), start)
    assert "decision 'off' (now 'cv')" in line and "outlier_distance 0.0 (now " in line
    assert "state_dir" not in line and "params_file" in line
    assert changed_settings(str(tmp_path), runtime) == ""
    data["settings"]["state_dir"] = "/elsewhere"                              # not compared
    (tmp_path / SNAPSHOT_NAME).write_text(json.dumps(data))
    assert changed_settings(str(tmp_path), runtime) == ""
    (tmp_path / SNAPSHOT_NAME).write_text("{cut")                            # tidy's business
    assert changed_settings(str(tmp_path), runtime) == ""



def test_start_warnings_read_the_snapshot_once_and_say_what_tidy_and_changed_settings_say(
        tmp_path, monkeypatch):
    from rbc_registration.pipeline.settings import Settings
    from rbc_registration.pipeline.snapshot import changed_settings, start_warnings

    start = Settings.from_mapping({"state_dir": str(tmp_path)})
    assert start_warnings(str(tmp_path), start) == []                       # nothing there
    runtime = start.replace(decision="off")
    data = {"format": SNAPSHOT_FORMAT,
            "settings": {k: getattr(runtime, k) for k in runtime.__dataclass_fields__}}
    (tmp_path / SNAPSHOT_NAME).write_text(json.dumps(data))
    (tmp_path / f"{SNAPSHOT_NAME}.tmp.1").write_text("half")
    expected = changed_settings(str(tmp_path), start)
    reads = []
    monkeypatch.setattr(snapshot, "read_snapshot", lambda p: reads.append(p) or read_snapshot(p))
    warnings = start_warnings(str(tmp_path), start)
    assert len(reads) == 1
    assert warnings[0].startswith(f"removed {SNAPSHOT_NAME}.tmp.1")
    assert warnings[1:] == [expected] and "decision 'off' (now 'cv')" in expected
    (tmp_path / SNAPSHOT_NAME).write_text("{cut")                            # moved aside, once
    warnings = start_warnings(str(tmp_path), start)
    assert len(warnings) == 1 and "not a valid snapshot" in warnings[0]
