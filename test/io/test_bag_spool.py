"""A bag's inputs read message by message into an on-disk spool (io/bag/spool): the same
messages back, the same evaluation, memory flat in the messages."""

import json
import math
import tracemalloc

import pytest

from rbc_registration.cli import main
from rbc_registration.io.bag.reader import read_bag
from rbc_registration.io.bag.records import DEFAULT_TOPICS
from rbc_registration.io.bag import spool as spool_module
from rbc_registration.io.bag.spool import CHUNK, InputSpool
from rbc_registration.io.evaluation import evaluate_contents
from rbc_registration.pipeline.inputs import PairMessage, PointMessage
from rbc_registration.pipeline.offline import infer_dimension, settings_for


def _messages(n):
    out = []
    for k in range(n):
        if k % 3 == 0:
            out.append(PairMessage(10 * k, k * 0.5, f"F{k % 7}", (k * 0.1, -0.0, math.nan),
                                   "tracker", (1e300, -2.5, k / 3), "world",
                                   None if k % 2 else k * 1_000_000_000 + 7,
                                   "" if k % 5 else "bad stamp", "g1" if k % 4 else "",
                                   "s2" if k > n // 2 else ""))
        else:
            out.append(PointMessage(10 * k + 1, "working" if k % 3 == 1 else "destination",
                                    (k * 0.25, 1.0 / (k + 1), -float(k)), "tracker" if k % 2 else
                                    "",
                                    k * 0.5 + 1e-9, "" if k % 11 else "no stamp"))
    return out


def test_the_spool_gives_back_what_it_was_given():
    msgs = _messages(2 * CHUNK + 17)
    spool = InputSpool()
    for m in msgs:
        spool.append(m)
    assert len(spool) == len(msgs)
    back = list(spool)
    assert len(back) == len(msgs)
    for a, b in zip(back, msgs):       # NaN is not == NaN: compare the texts of the tuples
        assert type(a) is type(b) and repr(a) == repr(b)
    assert [repr(m) for m in spool] == [repr(m) for m in back]    # iterated again
    assert repr(spool[5]) == repr(msgs[5]) and repr(spool[-1]) == repr(msgs[-1])
    assert [repr(m) for m in spool[3:9]] == [repr(m) for m in msgs[3:9]]
    with pytest.raises(IndexError):
        spool[len(msgs)]
    spool.close()


@pytest.fixture(scope="module")
def bags(tmp_path_factory):
    d = tmp_path_factory.mktemp("bags")
    out = {}
    for name, extra in (("pairs", ["--repeats", "4"]), ("points", ["--repeats", "3",
                                                                 "--points"]),
                        ("small", ["--repeats", "5", "--period", "0.001"]),
                        ("large", ["--repeats", "20", "--period", "0.001"])):
        path = d / name
        assert main(["synth-bag", str(path), "--cell", "B", "--storage", "mcap", "--quiet",
                     *extra]) == 0
        out[name] = path
    return out


@pytest.mark.parametrize("name", ["pairs", "points"])
def test_evaluation_of_the_spool_is_that_of_the_messages_in_memory(bags, name, capsys):
    contents = read_bag(bags[name], progress=False)
    capsys.readouterr()
    assert isinstance(contents.inputs, InputSpool)
    listed = contents._replace(inputs=tuple(contents.inputs))
    dim, _ = infer_dimension(contents.inputs, contents.targets)
    assert (dim, _) == infer_dimension(listed.inputs, listed.targets)
    settings = settings_for(dim, {})
    spooled = evaluate_contents(contents, settings)
    memory = evaluate_contents(listed, settings)
    assert json.dumps(spooled.report, sort_keys=True) == json.dumps(memory.report,
                                                                    sort_keys=True)
    assert spooled.warnings == memory.warnings and spooled.notes == memory.notes
    assert spooled.report["n_fiducials"] > 0


def _held(path):
    """The inputs read and the memory the reading leaves held (rosbags' own buffers, a chunk
    of the file at a time, are freed by then)."""
    tracemalloc.start()
    try:
        before = tracemalloc.get_traced_memory()[0]
        contents = read_bag(path, DEFAULT_TOPICS._replace(targets="/no_targets"),
                            progress=False)
        return len(contents.inputs), tracemalloc.get_traced_memory()[0] - before
    finally:
        tracemalloc.stop()


def test_reading_a_bag_holds_memory_flat_in_its_messages(bags, monkeypatch):
    # records written 256 at a time, so that both bags span several writes
    monkeypatch.setattr(spool_module, "CHUNK", 256)
    (n_small, small), (n_large, large) = _held(bags["small"]), _held(bags["large"])
    assert n_large == 4 * n_small and n_small > 2 * 256
    assert large <= 1.3 * small, (small, large)
    # the same inputs held as Python tuples (as the bag was read before the spool) grow
    spool = read_bag(bags["large"], progress=False).inputs
    tracemalloc.start()
    try:
        listed = tuple(spool)
        as_tuples = tracemalloc.get_traced_memory()[0]
    finally:
        tracemalloc.stop()
    assert len(listed) == n_large and as_tuples > 200 * n_large
