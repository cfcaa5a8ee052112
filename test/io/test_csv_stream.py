"""FIDUCIALS.csv read as a stream (io/csv_stream): the in-memory reader's fiducials, floats,
notes and errors; register's JSON unchanged; memory flat in the rows."""

import csv
import io
import json
import tracemalloc

import numpy as np
import pytest

from rbc_registration.cli import main
from rbc_registration.core.decision.noise import repeat_stats
from rbc_registration.core.synthetic.cells import make_cell
from rbc_registration.core.synthetic.structure import make_robot_cell, moved_sessions
from rbc_registration.io import csv_stream
from rbc_registration.io import progress as progress_module
from rbc_registration.io.csv_io import MAX_CANDIDATE_ROWS, CsvError, read_fiducials, read_targets
from rbc_registration.io.csv_stream import FiducialSums, read_fiducial_sums


def _write(path, header, rows, newline="\n"):
    with open(path, "w", newline="") as fh:
        w = csv.writer(fh, lineterminator=newline)
        w.writerow(header)
        w.writerows(rows)
    return path


def _repeats_rows(seed=0, repeats=3):
    cell = make_cell("B", seed, repeats=repeats)
    rows = []
    for k in range(repeats):
        for fid, m, t in zip(cell.fiducial_ids, cell.fiducial_measurements, cell.fiducial_truth):
            rows.append([fid, *m[k], *t])
    return rows


H3 = ["id", "wx", "wy", "wz", "dx", "dy", "dz"]


def _cases(d):
    """Files with repeats, outliers, copies, blank and padded fields, CRLF, quotes, groups,
    sessions (moved and kept apart) and a 2D read of a 3D file: (path, read_fiducials kwargs)."""
    rows = _repeats_rows()
    out = [(_write(d / "repeats.csv", H3, rows), {})]
    odd = [list(r) for r in rows]
    odd[40][1] += 5.0                                   # a working-frame outlier: ignored
    odd[41][2] -= 7.0
    odd += [list(r) for r in rows[10:30]]               # a block pasted twice: copies
    out.append((_write(d / "odd.csv", H3, odd), {}))
    out.append((_write(d / "odd_crlf.csv", H3, odd, "\r\n"), {}))
    text = (d / "odd.csv").read_text().splitlines()
    text[5] = "  " + text[5].replace(",", " , ")         # padded fields
    text.insert(9, "")                                  # blank lines, a row of empty fields
    text.insert(20, ",,,,,,")
    (d / "padded.csv").write_text("\n".join(text) + "\n")
    out.append((d / "padded.csv", {}))
    quoted = [r if k % 50 else [f'"{r[0]}"', *r[1:]] for k, r in enumerate(odd)]
    (d / "quoted.csv").write_text(",".join(H3 + ["note"]) + "\n" + "".join(
        ",".join(map(str, r)) + (',"two\nlines"' if k == 60 else ",") + "\n"
        for k, r in enumerate(quoted)))
    out.append((d / "quoted.csv", {}))
    out.append((d / "odd.csv", {"dim": 2}))             # z columns dropped: the tilt note
    out.append((d / "odd.csv", {"outlier_distance": 0.05}))
    out.append((d / "odd.csv", {"outlier_distance": 0}))
    robot = make_robot_cell(0)
    out.append((_write(d / "grouped.csv", ["id", "group", "wx", "wy", "wz", "dx", "dy", "dz"],
                       [[i, g, *p, *q] for i, g, p, q in zip(
                           robot.fiducial_ids, robot.fiducial_groups, robot.working,
                           robot.destination)]), {}))
    sc = moved_sessions(make_cell("RA", 0, repeats=1), 0, 3.0)
    out.append((_write(d / "sessions.csv", ["id", "session", "wx", "wy", "dx", "dy"],
                       [[i, s, *p, *q] for i, s, p, q in zip(sc.ids, sc.sessions, sc.working,
                                                              sc.destination)]), {}))
    out.append((d / "sessions.csv", {"reference_sessions": ["s1"]}))
    cell = make_cell("RA", 1, repeats=1)
    apart = [[i, "a", *m[0], *t] for i, m, t in zip(cell.fiducial_ids,
                                                    cell.fiducial_measurements,
                                                    cell.fiducial_truth)]
    apart += [["F000", "b", *(cell.fiducial_measurements[0][0] + 3), *cell.fiducial_truth[0]],
              ["NEW1", "b", 900.0, 900.0, 900.0, 900.0]]
    out.append((_write(d / "apart.csv", ["id", "session", "wx", "wy", "dx", "dy"], apart), {}))
    return out


def _same(table, sums: FiducialSums):
    assert sums.ids == table.ids
    np.testing.assert_array_equal(sums.working, table.working)
    np.testing.assert_array_equal(sums.destination, table.destination)
    stats = repeat_stats(table.working_repeats, table.dimension)
    np.testing.assert_array_equal(sums.repeat_stats.counts, stats.counts)
    np.testing.assert_array_equal(sums.repeat_stats.variances, stats.variances)
    assert sums.notes == table.notes
    assert sums.groups == table.groups and sums.dimension == table.dimension
    assert (sums.sessions is None) == (table.sessions is None)
    if table.sessions is not None:
        assert sums.sessions.to_list() == table.sessions.to_list()


@pytest.fixture(scope="module")
def cases(tmp_path_factory):
    return _cases(tmp_path_factory.mktemp("stream"))


def test_the_stream_reads_what_the_in_memory_reader_reads(cases):
    notes = []
    for path, kwargs in cases:
        table = read_fiducials(path, **kwargs)
        _same(table, read_fiducial_sums(path, **kwargs))
        notes += table.notes
    # the cases hold what they are meant to: copies, ignored outliers, sessions, the z note
    text = " ".join(notes)
    for said in ("repeat a run of earlier rows", "row ignored", "moved against", "kept apart",
                 "2D"):
        assert said in text, said


def test_small_chunks_batches_and_blocks_read_the_same(cases, monkeypatch):
    for name, value in (("CHUNK_ROWS", 7), ("BLOCK_CHARS", 300), ("BATCH_ROWS", 20),
                        ("RULE_BLOCK", 3), ("HASH_BUCKET_ROWS", 16)):
        monkeypatch.setattr(csv_stream, name, value)
    for path, kwargs in cases:
        _same(read_fiducials(path, **kwargs), read_fiducial_sums(path, **kwargs))


BAD = [
    "",
    "\nid,wx,wy,dx,dy\na,0,0,0,0\n",
    "sep=,\nid,wx,wy,dx,dy\n",
    "id;wx;wy;dx;dy\na;0;0;0;0\n",
    "id,wx,wx,wy,dx,dy\na,0,0,0,0,0\n",
    "id,wx,wy,dx\na,0,0,0\n",
    "id,wx,wy,dx,dy\n",
    "id,wx,wy,dx,dy\na,0,0,0,0\nb,1,0,x,0\nc,0,1,0,1,7\n",      # extra field wins over 'x'
    "id,wx,wy,dx,dy\na,0,0,0,0\nb,1,0,1_0,0\n",
    "id,wx,wy,dx,dy\na,0,0,0,0\nb,1,0,inf,0\n",
    "id,wx,wy,dx,dy\na,0,0,0,0\nb,1,0,1e300,0\n",
    "id,wx,wy,dx,dy\na,0,0,0,0\n,1,0,1,0\n",
    "id,wx,wy,dx,dy\na,0,0,0,0\nb,1,0,,0\n",
    "id,wx,wy,dx,dy\na,0,0,0,0\nb,1,0\n",
    "id,wx,wy,dx,dy,note\na,0,0,0,0,\"open\nb,1,0,1,0,\nc,0,1,0,1,\n",
    "id,wx,wy,wz,dx,dy\na,0,0,0,0,0\n",
    "id,group,wx,wy,dx,dy\na,g1,0,0,0,0\nb,g1,1,0,1,0\na,g2,0,0,0,0\n",
    "id,wx,wy,dx,dy\na,0,0,0,0\nb,1,0,1,0\nc,0,1,0,1\na,0,0,5,5\n",   # a conflict
    "id,wx,wy,dx,dy\na,0,0,0,0\nb,1,0,1,0\nc,0,1,0,1\nb,1,0\n\na,0,0,x,5\n",
]


@pytest.mark.parametrize("text", BAD)
def test_errors_are_the_in_memory_readers(tmp_path, text):
    path = tmp_path / "bad.csv"
    path.write_text(text)
    with pytest.raises(CsvError) as memory:
        read_fiducials(path)
    with pytest.raises(CsvError) as stream:
        read_fiducial_sums(path)
    assert str(stream.value) == str(memory.value)
    assert len(str(stream.value).splitlines()) <= 2


def test_a_file_that_is_no_text_is_one_line(tmp_path):
    path = tmp_path / "u16.csv"
    path.write_bytes("id,wx,wy,dx,dy\na,0,0,0,0\n".encode("utf-16"))
    with pytest.raises(CsvError, match="UTF-16") as stream:
        read_fiducial_sums(path)
    with pytest.raises(CsvError) as memory:
        read_fiducials(path)
    assert str(stream.value) == str(memory.value)
    with pytest.raises(CsvError, match="no such file"):
        read_fiducial_sums(tmp_path / "missing.csv")


def _in_memory(path, dim=None, outlier_distance=None, reference_sessions=None, progress=False):
    """register's reading before the stream: read_fiducials, the repeats' statistics."""
    t = read_fiducials(path, dim, outlier_distance, reference_sessions)
    return FiducialSums(t.ids, t.working, t.destination,
                        repeat_stats(t.working_repeats, t.dimension), t.dimension, t.notes,
                        t.groups, t.sessions)


def test_register_json_is_the_same_streamed_and_in_memory(cases, tmp_path, monkeypatch,
                                                          capsys):
    d = cases[0][0].parent
    robot = make_robot_cell(0)
    targets = _write(tmp_path / "targets.csv", H3, [
        [f"T{k}", *p, *q] for k, (p, q) in enumerate(zip(robot.target_working,
                                                          robot.target_truth))])
    sc = moved_sessions(make_cell("RA", 0, repeats=1), 0, 3.0)
    k = len(sc.target_truth)
    session_targets = _write(tmp_path / "tgt_s.csv", ["id", "session", "wx", "wy", "dx", "dy"],
                             [[i, s, *p, *sc.target_truth[n % k]] for n, (i, s, p) in enumerate(
                                 zip(sc.target_ids, sc.target_sessions, sc.target_working))])
    runs = [[d / "odd.csv"], [d / "padded.csv", "--outlier-distance", "0.05"],
            [d / "grouped.csv", "--targets", targets],
            [d / "sessions.csv", "--targets", session_targets], [d / "apart.csv"]]
    for k, args in enumerate(runs):
        texts = []
        for how in ("stream", "memory"):
            if how == "memory":
                monkeypatch.setattr(csv_stream, "read_fiducial_sums", _in_memory)
            out = tmp_path / f"{k}_{how}.json"
            assert main(["register", *map(str, args), "--json", str(out)]) == 0
            printed = capsys.readouterr()
            texts.append((out.read_text(), printed.out.replace(str(out), ""), printed.err))
            monkeypatch.undo()
        assert texts[0] == texts[1], args
        assert json.loads(texts[0][0])["n_fiducials"] > 0


def _peak(read, path):
    tracemalloc.start()
    try:
        read(path)
        return tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()


def test_memory_is_flat_in_the_rows(tmp_path, monkeypatch):
    # a long file of 40 fiducials' repeats: the stream's peak is the same at 4 x the rows
    # (chunks, blocks and batches set small so that both files span many of them); the
    # in-memory reader's grows with them
    for name, value in (("CHUNK_ROWS", 1024), ("BLOCK_CHARS", 1 << 16), ("BATCH_ROWS", 4096)):
        monkeypatch.setattr(csv_stream, name, value)
    rng = np.random.default_rng(3)
    points = rng.uniform(0, 1000, (40, 3))
    paths = []
    for repeats in (250, 1000):
        rows = [[f"P{j}", *(points[j] + rng.normal(0, 0.01, 3)), *points[j]]
                for _ in range(repeats) for j in range(40)]
        paths.append(_write(tmp_path / f"long{repeats}.csv", H3, rows))
    small, large = (_peak(read_fiducial_sums, p) for p in paths)
    assert large <= 1.3 * small, (small, large)
    memory_small, memory_large = (_peak(read_fiducials, p) for p in paths)
    assert memory_large >= 3 * memory_small
    assert large < memory_large / 10


class _Terminal(io.StringIO):
    def isatty(self):
        return True


def test_progress_is_a_line_on_a_terminal_and_quiet_when_piped(monkeypatch):
    monkeypatch.setattr(progress_module.time, "monotonic", iter(range(0, 1000, 1)).__next__)
    tty, pipe = _Terminal(), io.StringIO()
    for stream in (tty, pipe):
        bar = progress_module.Progress("reading f.csv", 10, stream=stream, every_s=2)
        for _ in range(10):
            bar.update()
        bar.done()
    assert pipe.getvalue() == ""
    shown = tty.getvalue()
    assert shown.endswith("reading f.csv [" + "#" * 30 + "] 10/10 (100%)\n")
    assert 3 <= shown.count("\r") <= 6          # redrawn every 2 s of the 10, not per item


def test_reading_with_progress_prints_nothing_when_piped(cases, capsys):
    path = cases[0][0]
    assert read_fiducial_sums(path, progress=True).ids == read_fiducials(path).ids
    assert capsys.readouterr().err == ""


def test_a_candidates_file_past_the_limit_is_refused_reading_no_further(tmp_path, capsys):
    path = tmp_path / "candidates.csv"
    rows = "".join(f"C{k},{k},0,0\n" for k in range(5))
    # 1 MB of rows past the limit, then bytes that are no UTF-8: reading on would fail on them
    path.write_bytes(b"id,wx,wy,wz\n" + rows.encode() + b"C8,1,0,0\n" * 100_000
                     + b"C9,\xff\xfe,0,0\n")
    with pytest.raises(CsvError, match=r"more than 5 candidate rows \(row 7\): refused") as exc:
        read_targets(path, 3, kind="candidate", max_rows=5)
    assert len(str(exc.value).splitlines()) == 1
    ok = tmp_path / "ok.csv"
    ok.write_text("id,wx,wy,wz\n" + rows)
    assert read_targets(ok, 3, kind="candidate", max_rows=5).ids == tuple(
        f"C{k}" for k in range(5))
    with pytest.raises(SystemExit):
        main(["plan", "--help"])
    assert f"at most {MAX_CANDIDATE_ROWS:,} rows" in capsys.readouterr().out.replace("\n", " ")
