"""The mcap CRC checks (rbc_registration.io.bag.mcap_crc) on every rosbags version this package
supports: a flipped bit under a chunk's or the summary's CRC is one BagError naming the byte
offset; a CRC of 0 checks nothing; a file cut short is still the reader's to report. No rclpy."""

import struct
import zlib
from pathlib import Path

import pytest

from rbc_registration.core.synthetic.cells import make_cell
from rbc_registration.io.bag import mcap_crc
from rbc_registration.io.bag.reader import read_bag, read_raw
from rbc_registration.io.bag.records import BagError
from rbc_registration.io.bag.synthetic import cell_messages
from rbc_registration.io.bag.writer import write_bag

MAGIC = mcap_crc.MAGIC


def _zstd_compress(data: bytes) -> bytes:
    try:
        from compression import zstd
    except ImportError:
        try:
            from backports import zstd
        except ImportError:
            import zstandard
            return zstandard.ZstdCompressor().compress(data)
    return zstd.compress(data)


def _lz4_compress(data: bytes) -> bytes:
    from lz4.frame import compress
    return compress(data)


COMPRESSORS = {"": lambda data: data, "zstd": _zstd_compress, "lz4": _lz4_compress}


def _record(op: int, body: bytes) -> bytes:
    return struct.pack("<BQ", op, len(body)) + body


def _chunk(records: bytes, compression: str, crc: int) -> bytes:
    data = COMPRESSORS[compression](records)
    name = compression.encode()
    return _record(0x06, struct.pack("<QQQI", 1, 2, len(records), crc)
                   + struct.pack("<I", len(name)) + name + struct.pack("<Q", len(data)) + data)


def _mcap(chunks: list[bytes], summary: bytes = b"", summary_crc: bool = True) -> bytes:
    """A minimal mcap: magic, header, chunks, DataEnd, an optional summary, footer, magic."""
    out = MAGIC + _record(0x01, struct.pack("<I", 4) + b"ros2" + struct.pack("<I", 0))
    out += b"".join(chunks) + _record(0x0F, struct.pack("<I", 0))
    start = len(out) if summary else 0
    out += summary
    footer = struct.pack("<BQQQ", 0x02, 20, start, 0)
    crc = zlib.crc32(out[start:] + footer) if summary and summary_crc else 0
    return out + footer + struct.pack("<I", crc) + MAGIC


MESSAGES = b"".join(_record(0x05, struct.pack("<HIQQ", 1, k, k, k) + bytes(range(40)))
                    for k in range(30))


@pytest.mark.parametrize("compression", ["", "zstd", "lz4"])
def test_a_chunk_whose_records_changed_fails_its_crc(tmp_path, compression):
    f = tmp_path / "x.mcap"
    good = _chunk(MESSAGES, compression, zlib.crc32(MESSAGES))
    f.write_bytes(_mcap([good, good]))
    mcap_crc.check_mcap(f)                        # right CRCs pass
    wrong = _chunk(MESSAGES, compression, zlib.crc32(MESSAGES) ^ 1)
    f.write_bytes(_mcap([good, wrong]))
    with pytest.raises(BagError, match=rf"bag {f}: corrupt: mcap chunk at byte "
                                       rf"{len(MAGIC) + 21 + len(good)} fails its CRC-32 check "
                                       r"\(stored 0x[0-9a-f]{8}, computed 0x[0-9a-f]{8}\)"):
        mcap_crc.check_mcap(f)


def test_a_crc_of_zero_checks_nothing_and_a_cut_file_is_left_to_the_reader(tmp_path):
    f = tmp_path / "x.mcap"
    data = _mcap([_chunk(MESSAGES, "", 0), _chunk(MESSAGES, "", zlib.crc32(MESSAGES) ^ 1)])
    f.write_bytes(data[:len(data) - 200])           # the wrong chunk is cut: not checked
    mcap_crc.check_mcap(f)
    f.write_bytes(_mcap([_chunk(MESSAGES, "", 0)]))
    mcap_crc.check_mcap(f)
    f.write_bytes(b"not an mcap file at all")
    mcap_crc.check_mcap(f)


def test_a_compressed_chunk_that_does_not_decompress_is_corrupt(tmp_path):
    f = tmp_path / "x.mcap"
    chunk = bytearray(_chunk(MESSAGES, "lz4", zlib.crc32(MESSAGES)))
    chunk[60:70] = b"\xff" * 10                      # inside the lz4 frame
    f.write_bytes(_mcap([bytes(chunk)]))
    with pytest.raises(BagError, match=r"corrupt: mcap chunk at byte \d+ cannot be "
                                       r"decompressed \(lz4: "):
        mcap_crc.check_mcap(f)


def test_the_summary_crc_covers_the_summary_and_the_footer_offsets(tmp_path):
    f = tmp_path / "x.mcap"
    summary = _record(0x0B, bytes(range(46)))        # e.g. Statistics
    data = bytearray(_mcap([_chunk(MESSAGES, "", 0)], summary))
    f.write_bytes(bytes(data))
    mcap_crc.check_mcap(f)
    at = len(data) - len(MAGIC) - 29 - len(summary) + 12
    data[at] ^= 0x04
    f.write_bytes(bytes(data))
    with pytest.raises(BagError, match=r"corrupt: mcap summary \(from byte \d+\) fails its "
                                       r"CRC-32 check"):
        mcap_crc.check_mcap(f)
    f.write_bytes(_mcap([_chunk(MESSAGES, "", 0)], summary, summary_crc=False))
    mcap_crc.check_mcap(f)


# -- through read_bag / read_raw, on a bag write_bag wrote ----------------------------------------

def _storage(bag: Path) -> Path:
    return next(bag.glob("*.mcap"))


def _chunk_and_summary_crcs(data: bytes) -> tuple[list[int], int]:
    """The CRC fields as stored: of each chunk, and of the summary (in the footer)."""
    crcs, i = [], len(MAGIC)
    while data[i] != 0x0F:                          # records up to DataEnd
        if data[i] == 0x06:
            crcs.append(struct.unpack_from("<I", data, i + 33)[0])
        i += 9 + struct.unpack_from("<Q", data, i + 1)[0]
    return crcs, struct.unpack_from("<I", data, len(data) - len(MAGIC) - 4)[0]


@pytest.fixture
def crc_bag(tmp_path):
    """An mcap bag as write_bag writes it (synth-bag): with its CRCs, as rosbag2 writes them."""
    bag = tmp_path / "crc"
    write_bag(bag, cell_messages(make_cell("RA", seed=0)), "mcap", progress=False)
    return bag, bytearray(_storage(bag).read_bytes())


def test_a_bag_this_package_writes_carries_the_crcs(crc_bag):
    bag, data = crc_bag
    chunks, summary = _chunk_and_summary_crcs(data)
    assert chunks and all(chunks) and summary
    mcap_crc.check_mcap(_storage(bag))
    copy = bag.parent / "copy.mcap"                  # written again: the same bytes
    copy.write_bytes(bytes(data))
    mcap_crc.write_crcs(copy)
    assert copy.read_bytes() == bytes(data)


def test_a_flipped_bit_in_a_coordinate_is_one_bag_error_not_a_wrong_coordinate(crc_bag):
    bag, data = crc_bag
    good = read_bag(bag, progress=False)            # the CRCs write_bag wrote are right
    assert good.inputs
    data[len(data) // 3] ^= 0x10                    # inside the (one) chunk's messages
    _storage(bag).write_bytes(bytes(data))
    for read in (read_bag, read_raw):
        with pytest.raises(BagError, match=r"corrupt: mcap chunk at byte \d+ fails its CRC-32"):
            read(bag, progress=False)


def test_a_flipped_bit_in_the_summary_is_one_bag_error(crc_bag):
    bag, data = crc_bag
    start = struct.unpack_from("<Q", data, len(data) - len(MAGIC) - 20)[0]
    data[start + 20] ^= 0x01
    _storage(bag).write_bytes(bytes(data))
    with pytest.raises(BagError, match=r"corrupt: mcap summary \(from byte \d+\) fails"):
        read_bag(bag, progress=False)


def test_any_flipped_bit_is_refused_in_one_line_or_changes_nothing_read(crc_bag):
    """Random bit flips anywhere in the file (chunks, message indexes, summary, footer): each
    read is a one-line BagError, or the very messages of the intact file (a flip in bytes no
    message depends on, such as a chunk's time range)."""
    import random

    bag, good = crc_bag
    ref = read_bag(bag, progress=False)
    rng = random.Random(4)
    refused = 0
    for _ in range(40):
        data = bytearray(good)
        for _ in range(rng.choice((1, 2, 8))):
            data[rng.randrange(len(data))] ^= 1 << rng.randrange(8)
        _storage(bag).write_bytes(bytes(data))
        try:
            got = read_bag(bag, progress=False)
        except BagError as exc:
            assert "\n" not in str(exc)
            refused += 1
        else:
            assert (got.inputs, got.targets) == (ref.inputs, ref.targets)
    assert refused >= 30


def test_only_the_files_the_metadata_lists_are_checked(crc_bag):
    """A damaged .mcap beside a bag (an old take copied into the directory) is not the bag's:
    the bag reads; a bag's own damaged file is refused."""
    bag, data = crc_bag
    damaged = bytearray(data)
    damaged[len(damaged) // 3] ^= 0x10
    own = _storage(bag)
    (bag / "old_take.mcap").write_bytes(bytes(damaged))
    assert mcap_crc.mcap_files(bag) == [own] and len(list(bag.glob("*.mcap"))) == 2
    assert read_bag(bag, progress=False).inputs
    (bag / "metadata.yaml").write_text("not: [a, bag")    # unreadable: the reader says so
    assert mcap_crc.mcap_files(bag) == []


def test_a_compression_without_its_library_here_is_left_to_the_reader(tmp_path, monkeypatch):
    """No decompression library for a chunk's compression (e.g. lz4 where rosbags installed
    safelz4): the check is skipped, not the file called damaged."""
    def missing():
        raise ImportError("No module named 'lz4'")

    monkeypatch.setitem(mcap_crc.DECOMPRESSORS, "lz4", missing)
    f = tmp_path / "x.mcap"
    f.write_bytes(_mcap([_chunk(MESSAGES, "lz4", zlib.crc32(MESSAGES) ^ 1)]))
    mcap_crc.check_mcap(f)


def test_a_memory_error_of_the_storage_library_is_one_bag_error(tmp_path, monkeypatch):
    """A flipped record length in an mcap without chunks (rosbag2's fastwrite preset: no CRC)
    makes rosbags' reader ask for a huge buffer (a MemoryError must not escape)."""
    from rosbags.rosbag2 import Reader

    bag = tmp_path / "mem"
    write_bag(bag, cell_messages(make_cell("A", seed=0)), "mcap", progress=False)
    real = Reader.messages

    def messages(self, *args, **kwargs):
        for k, item in enumerate(real(self, *args, **kwargs)):
            if k == 5:
                raise MemoryError
            yield item

    monkeypatch.setattr(Reader, "messages", messages)
    for read in (read_bag, read_raw):
        with pytest.raises(BagError, match=r"truncated or corrupt after 5 message\(s\): "
                                           "MemoryError"):
            read(bag, progress=False)
