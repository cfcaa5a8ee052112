"""rosbag2 reading and writing (rbc_registration.io.bag): round trips through both storages, and a
clear BagError (never a traceback) for every kind of bad bag. No rclpy."""

import os
import shutil
from pathlib import Path

import numpy as np
import pytest
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

from rbc_registration import cli
from rbc_registration.core.synthetic.cells import make_cell
from rbc_registration.io.bag import typestore
from rbc_registration.io.bag.reader import read_bag, read_raw
from rbc_registration.io.bag.records import (DEFAULT_TOPICS, FIDUCIAL_PAIR, SYNTH_PERIOD_S,
                                             BagError,
                                             PairMessage, PointMessage, Topics)
from rbc_registration.io.bag.synthetic import cell_messages
from rbc_registration.io.bag.writer import write_bag


@pytest.fixture(scope="module")
def cell_a():
    return make_cell("A", seed=1, repeats=2)


@pytest.fixture(scope="module")
def bags(tmp_path_factory, cell_a):
    """Cell A (3D, 2 repeats) as a FiducialPair bag in each storage, and as point pairs."""
    root = tmp_path_factory.mktemp("bags")
    out = {}
    for storage in ("sqlite3", "mcap"):
        out[storage] = root / f"a_{storage}"
        write_bag(out[storage], cell_messages(cell_a), storage, progress=False)
    out["points"] = root / "a_points"
    write_bag(out["points"], cell_messages(cell_a, points=True), "mcap", progress=False)
    return out


def storage_file(bag: Path) -> Path:
    return next(p for p in bag.iterdir() if p.suffix in (".db3", ".mcap"))


@pytest.mark.parametrize("storage", ["sqlite3", "mcap"])
def test_round_trip_in_metres_with_increasing_stamps(bags, cell_a, storage):
    contents = read_bag(bags[storage], progress=False)
    j = len(cell_a.fiducial_ids)
    assert contents.counts == {DEFAULT_TOPICS.fiducial_pairs: 2 * j,
                               DEFAULT_TOPICS.targets: 2 * len(cell_a.target_ids)}
    assert all(isinstance(m, PairMessage) for m in contents.inputs)
    first = contents.inputs[:j]  # the first pass visits every fiducial once
    assert [m.fiducial_id for m in first] == list(cell_a.fiducial_ids)
    np.testing.assert_array_equal([m.working for m in first],
                                  [w[0] * 1e-3 for w in cell_a.fiducial_measurements])
    np.testing.assert_array_equal([m.destination for m in first], cell_a.fiducial_truth * 1e-3)
    assert {m.working_frame for m in contents.inputs} == {"tracker"}
    assert {m.destination_frame for m in contents.inputs} == {"world"}
    stamps = np.array([m.stamp_s for m in contents.inputs + contents.targets])
    np.testing.assert_allclose(np.diff(stamps), SYNTH_PERIOD_S, atol=1e-6)   # the default
    np.testing.assert_array_equal([m.destination for m in contents.targets[:16]],
                                  cell_a.target_truth * 1e-3)


@pytest.mark.parametrize("storage", ["sqlite3", "mcap"])
def test_single_storage_file_reads_like_the_directory(bags, storage):
    whole = read_bag(bags[storage], progress=False)
    single = read_bag(storage_file(bags[storage]), progress=False)
    assert single.inputs == whole.inputs and single.targets == whole.targets


def test_point_pairs(bags, cell_a):
    contents = read_bag(bags["points"], progress=False)
    assert all(isinstance(m, PointMessage) for m in contents.inputs)
    working = [m for m in contents.inputs if m.stream == "working"]
    destination = [m for m in contents.inputs if m.stream == "destination"]
    assert len(working) == len(destination) == 2 * len(cell_a.fiducial_ids)
    assert [m.stamp_s for m in working] == [m.stamp_s for m in destination]


def test_two_dimensional_cell_has_zero_z(tmp_path):
    bag = tmp_path / "ra"
    write_bag(bag, cell_messages(make_cell("RA", seed=0)), progress=False)
    contents = read_bag(bag, progress=False)
    assert {m.working[2] for m in contents.inputs} == {0.0}
    assert {m.destination[2] for m in contents.inputs + contents.targets} == {0.0}


def test_other_node_name_and_read_raw(tmp_path, cell_a):
    topics = Topics.for_node("cell_a")
    assert topics.fiducial_pairs == "/cell_a/fiducial_pairs"
    bag = tmp_path / "named"
    write_bag(bag, cell_messages(cell_a, topics), "mcap", progress=False)
    raw = read_raw(bag, progress=False)
    assert {m.topic for m in raw} == {"/cell_a/fiducial_pairs", "/cell_a/targets"}
    assert [m.log_ns for m in raw] == sorted(m.log_ns for m in raw)
    with pytest.raises(BagError, match="none of the input topics"):
        read_bag(bag, progress=False)
    assert read_bag(bag, topics, progress=False).counts[topics.fiducial_pairs] > 0


# -- bad bags: a BagError naming the problem ----------------------------------------------------
def test_missing_bag(tmp_path):
    with pytest.raises(BagError, match="no such file or directory"):
        read_bag(tmp_path / "nope", progress=False)


def test_directory_without_metadata(tmp_path):
    with pytest.raises(BagError, match="no metadata.yaml"):
        read_bag(tmp_path, progress=False)


def test_unrecognised_file(tmp_path):
    f = tmp_path / "cell.txt"
    f.write_text("id,wx\n")
    with pytest.raises(BagError, match="cannot open.*Unrecognized storage format"):
        read_bag(f, progress=False)


def test_malformed_metadata(tmp_path, bags):
    bag = tmp_path / "bad_meta"
    shutil.copytree(bags["sqlite3"], bag)
    (bag / "metadata.yaml").write_text("rosbag2_bagfile_information: [1, 2\n")
    with pytest.raises(BagError, match="cannot open"):
        read_bag(bag, progress=False)


@pytest.mark.parametrize("storage", ["sqlite3", "mcap"])
@pytest.mark.parametrize("fraction", [0.02, 0.6])
def test_truncated_bag(tmp_path, bags, storage, fraction):
    bag = tmp_path / "cut"
    shutil.copytree(bags[storage], bag)
    f = storage_file(bag)
    data = f.read_bytes()
    f.write_bytes(data[:int(len(data) * fraction)])
    for path in (bag, f):
        with pytest.raises(BagError, match="truncated or corrupt"):
            read_bag(path, progress=False)


@pytest.mark.parametrize("storage", ["sqlite3", "mcap"])
def test_a_fifo_or_directory_in_place_of_a_bag_file_is_refused_not_waited_on(tmp_path, bags,
                                                                          storage):
    """a FIFO as the storage file (or a single-file bag) blocked open() for ever, a
    FIFO metadata.yaml read as 'no metadata.yaml', a directory as 'disk I/O error'."""
    bag = tmp_path / "fifo"
    shutil.copytree(bags[storage], bag)
    f = storage_file(bag)
    f.unlink()
    os.mkfifo(f)
    for path in (bag, f):
        with pytest.raises(BagError, match=f"{f.name} is a FIFO, not a regular file: refused"):
            read_bag(path, progress=False)
    f.unlink()
    f.mkdir()
    with pytest.raises(BagError, match=f"{f.name} is a directory, not a regular file"):
        read_bag(bag, progress=False)
    meta = tmp_path / "fifo_meta"
    shutil.copytree(bags[storage], meta)
    (meta / "metadata.yaml").unlink()
    os.mkfifo(meta / "metadata.yaml")
    with pytest.raises(BagError, match="metadata.yaml is a FIFO, not a regular file: refused"):
        read_bag(meta, progress=False)


def test_a_topic_renamed_in_metadata_yaml_alone_is_refused_not_lost(tmp_path, bags):
    """renaming a topic in metadata.yaml (not in the .db3) made rosbags read nothing
    of it; the targets vanished with warnings: [] and only a 'messages lost?' note."""
    bag = tmp_path / "renamed"
    shutil.copytree(bags["sqlite3"], bag)
    meta = bag / "metadata.yaml"
    meta.write_text(meta.read_text().replace("name: /registration_node/targets",
                                             "name: /registration_node/targetz"))
    with pytest.raises(BagError, match=r"metadata.yaml and the storage disagree on the topics: "
                                       r"with messages only in the storage: /registration_node/"
                                       r"targets \[rbc_registration_interfaces/msg/FiducialPair\]; "
                                       r"only in metadata.yaml: /registration_node/targetz"):
        read_bag(bag, progress=False)
    read_bag(bags["sqlite3"], progress=False)      # the bag as written reads


def test_corrupt_message_payload(tmp_path):
    """A message whose bytes do not decode as its type."""
    store = typestore.make_typestore()
    bag = tmp_path / "garbage"
    with Writer(bag, version=9, storage_plugin=StoragePlugin.MCAP) as w:
        conn = w.add_connection(DEFAULT_TOPICS.fiducial_pairs, FIDUCIAL_PAIR, typestore=store)
        w.write(conn, 1, b"\x00\x01\x00\x00\xff\xff")
    with pytest.raises(BagError, match="message 1 on /registration_node/fiducial_pairs cannot "
                                       "be decoded"):
        read_bag(bag, progress=False)


def test_required_topic_missing_names_the_bag_topics(bags):
    with pytest.raises(BagError, match=r"no topic /elsewhere .*topics in the bag: "
                                       r"/registration_node/fiducial_pairs"):
        read_bag(bags["sqlite3"], DEFAULT_TOPICS._replace(fiducial_pairs="/elsewhere"),
                 required=["/elsewhere"], progress=False)


def test_topic_with_wrong_type(bags):
    topics = DEFAULT_TOPICS._replace(working_point=DEFAULT_TOPICS.targets, targets="/none")
    with pytest.raises(BagError, match="has type rbc_registration_interfaces/msg/FiducialPair, "
                                       "expected geometry_msgs/msg/PointStamped"):
        read_bag(bags["sqlite3"], topics, progress=False)


def test_only_one_point_stream(tmp_path, cell_a):
    bag = tmp_path / "half"
    msgs = [m for m in cell_messages(cell_a, points=True)
            if m.topic != DEFAULT_TOPICS.destination_point]
    write_bag(bag, msgs, progress=False)
    with pytest.raises(BagError, match="cannot be paired"):
        read_bag(bag, progress=False)


def test_missing_interface_definitions(monkeypatch, tmp_path, bags):
    monkeypatch.setattr(typestore, "interface_msg_dirs", lambda: [tmp_path])
    with pytest.raises(BagError, match="missing type definitions: FiducialPair.msg"):
        read_bag(bags["sqlite3"], progress=False)


def test_bag_with_another_definition_of_fiducial_pair(tmp_path):
    store = get_typestore(Stores.ROS2_KILTED)
    store.register(get_types_from_msg("std_msgs/Header header\nstring fiducial_id\n",
                                      FIDUCIAL_PAIR))
    bag = tmp_path / "old_def"
    with Writer(bag, version=9, storage_plugin=StoragePlugin.SQLITE3) as w:
        w.add_connection(DEFAULT_TOPICS.fiducial_pairs, FIDUCIAL_PAIR, typestore=store)
    with pytest.raises(BagError, match="another definition of rbc_registration_interfaces/msg/"
                                       "FiducialPair"):
        read_bag(bag, progress=False)


def test_every_topic_leaves_out_one_of_another_definition_with_a_line(tmp_path):
    """replay reads every topic by default: an unrelated topic recorded with another definition
    (e.g. another ROS release's) is left out with one line, not the whole bag; named, refused."""
    store = get_typestore(Stores.ROS2_KILTED)
    other = get_typestore(Stores.EMPTY)                     # another release's Int32
    other.register(get_types_from_msg("int64 data\n", "std_msgs/msg/Int32"))
    bag = tmp_path / "mixed"
    with Writer(bag, version=9, storage_plugin=StoragePlugin.SQLITE3) as w:
        odd = w.add_connection("/odd", "std_msgs/msg/Int32", msgdef="int64 data\n",
                               rihs01=other.hash_rihs01("std_msgs/msg/Int32"))
        good = w.add_connection("/chatter", "std_msgs/msg/String", typestore=store)
        msg = store.types["std_msgs/msg/String"](data="hello")
        w.write(good, 5, store.serialize_cdr(msg, "std_msgs/msg/String"))
        w.write(odd, 6, bytes(12))
    lines = []
    out = read_raw(bag, progress=False, warn=lines.append)
    assert [m.topic for m in out] == ["/chatter"]
    assert len(lines) == 1 and "/odd was recorded with another definition of std_msgs/msg/Int32" \
        in lines[0] and lines[0].endswith(": skipped")
    with pytest.raises(BagError, match="another definition of std_msgs/msg/Int32"):
        read_raw(bag, ["/odd"], progress=False, warn=lines.append)
    with pytest.raises(BagError, match="another definition"):
        read_raw(bag, progress=False)                       # no one to tell: refused


def test_storage_must_be_known(tmp_path):
    with pytest.raises(BagError, match="storage must be one of sqlite3, mcap"):
        write_bag(tmp_path / "x", [], "zip")


def test_existing_output_is_not_overwritten(bags):
    with pytest.raises(BagError, match="exists already"):
        write_bag(bags["sqlite3"], [], progress=False)


# -- the command line: one line on stderr, exit 2, no traceback ---------------------------------
@pytest.mark.parametrize("args", [
    ["evaluate", "{tmp}/nope"],
    ["evaluate", "{tmp}"],
    ["evaluate", "{bag}", "--fiducial-topic", "/nope"],
    ["evaluate", "{bag}", "-p", "merge_radius:=abc"],
    ["evaluate", "{bag}", "-p", "no_such:=1"],
    ["replay", "{tmp}/nope"],
    ["replay", "{bag}", "--topics", "/nope"],
    ["synth-bag", "--cell", "RA", "{bag}"],
])
def test_cli_errors_are_one_clear_line(args, tmp_path, bags, capsys):
    argv = [a.format(tmp=tmp_path, bag=bags["sqlite3"]) for a in args]
    assert cli.main(argv) == 2
    err = capsys.readouterr().err
    assert f"rbc-registration {argv[0]}: error: " in err and "Traceback" not in err
    assert len(err.strip().splitlines()) == 1


def test_a_corrupt_database_page_is_one_bag_error(tmp_path):
    """64 bytes of 0xff in a data page of the .db3: rosbags reads it through apsw, whose
    CorruptError while iterating is not wrapped (a traceback, exit 1)."""
    bag = tmp_path / "page"
    write_bag(bag, cell_messages(make_cell("RA", seed=0)), "sqlite3", progress=False)
    f = storage_file(bag)
    data = bytearray(f.read_bytes())
    assert len(data) > 120_000
    data[100_000:100_064] = b"\xff" * 64
    f.write_bytes(bytes(data))
    with pytest.raises(BagError, match=r"truncated or corrupt after \d+ message\(s\)"):
        read_bag(bag, progress=False)


def test_messages_the_metadata_lists_but_the_storage_lost_are_reported(tmp_path, bags, capsys):
    """Rows deleted from the .db3 behind its metadata.yaml: rosbags reads what is left without a
    word; read_bag, read_raw and evaluate (a note, also in report.md) say how many are missing."""
    import sqlite3
    assert read_bag(bags["sqlite3"], progress=False).count_mismatches == ()
    bag = tmp_path / "lost"
    shutil.copytree(bags["sqlite3"], bag)
    with sqlite3.connect(storage_file(bag)) as db:
        (topic_id,) = db.execute("SELECT id FROM topics WHERE name = ?",
                                 (DEFAULT_TOPICS.fiducial_pairs,)).fetchone()
        db.execute("DELETE FROM messages WHERE id IN (SELECT id FROM messages WHERE topic_id = ? "
                   "LIMIT 7)", (topic_id,))
    contents = read_bag(bag, progress=False)
    listed = contents.counts[DEFAULT_TOPICS.fiducial_pairs] + 7
    (line,) = contents.count_mismatches
    assert f"{DEFAULT_TOPICS.fiducial_pairs}: the metadata lists {listed} message(s), " \
           f"{listed - 7} were read" in line and str(bag) in line
    warned = []
    read_raw(bag, progress=False, warn=warned.append)
    assert warned == [line]
    assert cli.main(["evaluate", str(bag), "--quiet", "--out", str(tmp_path / "out")]) == 0
    assert f"note: {line}" in capsys.readouterr().out
    assert f"lists {listed} message\\(s\\), {listed - 7} were read" in (
        tmp_path / "out" / "report.md").read_text()          # Markdown-escaped


def test_one_topic_named_for_two_inputs_is_refused(bags):
    same = DEFAULT_TOPICS._replace(targets=DEFAULT_TOPICS.fiducial_pairs)
    with pytest.raises(BagError, match="each topic can be one input only"):
        read_bag(bags["sqlite3"], same, progress=False)


def test_an_input_topic_listed_without_messages_decides_nothing(tmp_path, cell_a, capsys):
    """``ros2 bag record -a`` lists a topic that published nothing: a pair bag with an empty
    working_point connection was refused ('has working_point but not destination_point')."""
    bag = tmp_path / "record_a"
    write_bag(bag, cell_messages(cell_a), progress=False,
              empty=[(DEFAULT_TOPICS.working_point, "point")])
    contents = read_bag(bag, progress=False)
    assert contents.counts[DEFAULT_TOPICS.working_point] == 0
    assert contents.notes == (f"bag {bag}: {DEFAULT_TOPICS.working_point}: no messages "
                              "(ignored)",)
    assert cli.main(["evaluate", str(bag), "--quiet"]) == 0
    assert "working_point: no messages (ignored)" in capsys.readouterr().out
    # points on one stream and an empty other stream still cannot be paired
    half = tmp_path / "half"
    write_bag(half, [m for m in cell_messages(cell_a, points=True)
                     if m.topic != DEFAULT_TOPICS.destination_point], progress=False,
              empty=[(DEFAULT_TOPICS.destination_point, "point")])
    with pytest.raises(BagError, match="destination_point .no messages.: points cannot be "
                                       "paired"):
        read_bag(half, progress=False)


def test_the_messages_read_not_the_metadata_say_whether_a_topic_is_empty(tmp_path, cell_a):
    """A points bag whose metadata.yaml lists working_point with 0 messages while the storage
    holds them all was refused ('has destination_point but not working_point')."""
    bag = tmp_path / "points"
    write_bag(bag, cell_messages(cell_a, points=True), progress=False)
    meta = bag / "metadata.yaml"
    text = meta.read_text()
    block = text.index(f"name: {DEFAULT_TOPICS.working_point}")
    at = text.rindex("message_count:", 0, block)           # its entry starts with the count
    end = text.index("\n", at)
    meta.write_text(text[:at] + "message_count: 0" + text[end:])
    contents = read_bag(bag, progress=False)
    n = contents.counts[DEFAULT_TOPICS.working_point]
    assert n > 0 and not contents.notes
    assert contents.count_mismatches == (
        f"bag {bag}: {DEFAULT_TOPICS.working_point}: the metadata lists 0 message(s), {n} "
        "were read (the storage and its metadata disagree: messages lost?)",)
