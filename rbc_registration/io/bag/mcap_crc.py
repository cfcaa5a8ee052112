"""The CRC-32s of an mcap file, checked here so that the check does not depend on the rosbags
version (rosbags 0.11.0, the lowest this package supports, checks none of them), and written
into the files this package writes (:func:`write_crcs`; rosbags' writer leaves them 0):

- every Chunk's CRC of its uncompressed records (rosbag2's mcap writer writes it by default);
- the Summary's CRC (the chunk indexes and statistics a reader goes by), over the bytes from
  the summary's start through the footer's ``summary_offset_start`` field.

A CRC of 0 means "not computed" and checks nothing. The data section's
optional CRC (off by default in rosbag2) is not checked. A file cut short is left to the reader,
which names how many messages it read: only complete records are checked here.
"""

from __future__ import annotations

import struct
import zlib
from pathlib import Path
from typing import BinaryIO, Callable, Iterator, Optional

import yaml

from .records import BagError

MAGIC = b"\x89MCAP0\r\n"
OP_FOOTER, OP_CHUNK, OP_DATA_END = 0x02, 0x06, 0x0F
_RECORD = struct.Struct("<BQ")          # opcode, length of the record's body
_CHUNK = struct.Struct("<QQQI")         # start, end [ns], uncompressed size, uncompressed CRC
_FOOTER = struct.Struct("<BQQQI")       # opcode, length, summary_start, summary_offset_start, crc
_BLOCK = 1 << 22                        # bytes hashed at a time (memory stays bounded)


def _zstd() -> Callable[[bytes, int], bytes]:
    try:                                        # Python 3.14, and rosbags >= 0.11.x's backport
        from compression import zstd            # type: ignore[import-not-found]
    except ImportError:
        try:
            from backports import zstd          # type: ignore[import-not-found,no-redef]
        except ImportError:                     # rosbags 0.11.0 depends on zstandard
            import zstandard

            # streaming: a frame without its content size would otherwise allocate the
            # chunk's stated size, which a flipped bit can make huge
            return lambda data, _size: zstandard.ZstdDecompressor().decompressobj().decompress(
                data)
    return lambda data, _size: zstd.decompress(data)


def _lz4() -> Callable[[bytes, int], bytes]:
    try:                                        # rosbags installs safelz4 on newer Pythons
        from safelz4.frame import decompress    # type: ignore[import-not-found]
    except ImportError:
        from lz4.frame import decompress        # type: ignore[import-untyped,no-redef]

    return lambda data, _size: decompress(data)


#: Chunk compression name -> a factory of ``decompress(data, uncompressed_size)``.
DECOMPRESSORS: dict[str, Callable[[], Callable[[bytes, int], bytes]]] = {
    "": lambda: lambda data, _size: data, "zstd": _zstd, "lz4": _lz4}


def storage_files(path: Path) -> list[Path]:
    """The storage files of a bag: ``path`` itself, or the files its ``metadata.yaml`` lists
    (``relative_file_paths``, whether they exist or not). A metadata file that cannot be read
    gives none: opening the bag then says what is wrong."""
    if not path.is_dir():
        return [path]
    if not (path / "metadata.yaml").is_file():
        return []                               # a FIFO there would block read_text
    try:
        info = yaml.safe_load((path / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
        names = [str(name) for name in info["relative_file_paths"]]
    except (OSError, UnicodeDecodeError, yaml.YAMLError, KeyError, TypeError):
        return []
    return [path / name for name in names]


def mcap_files(path: Path) -> list[Path]:
    """The mcap files of a bag: ``path`` itself, or the ``.mcap`` files its ``metadata.yaml``
    lists (another file in the directory is not the bag's; :func:`storage_files`)."""
    return [f for f in storage_files(path) if f.suffix == ".mcap" and f.is_file()]


def check_mcap(path: Path) -> None:
    """Check the chunk and summary CRCs of one mcap file.

    :raises BagError: naming the file, the record's byte offset and the CRCs, when a CRC does
        not match or a chunk with a CRC cannot be decompressed.
    """
    with path.open("rb") as f:
        size = f.seek(0, 2)
        f.seek(0)
        if f.read(len(MAGIC)) != MAGIC:
            return                              # not an mcap file: the reader says so
        _check_chunks(f, size, path)
        _check_summary(f, size, path)


def _corrupt(path: Path, what: str) -> BagError:
    return BagError(f"bag {path}: corrupt: {what}; the file is damaged (a flipped bit or a bad "
                    "copy): record or copy it again")


def _chunks(f: BinaryIO, size: int) -> Iterator[tuple[int, int]]:
    """``(byte offset, body length)`` of each complete Chunk record of the data section."""
    pos = len(MAGIC)
    while pos + _RECORD.size <= size:
        f.seek(pos)
        op, length = _RECORD.unpack(f.read(_RECORD.size))
        end = pos + _RECORD.size + length
        if op in (OP_DATA_END, OP_FOOTER) or end > size:
            return                              # the data section ends, or the file is cut
        if op == OP_CHUNK and length >= _CHUNK.size + 4:
            yield pos, length
        pos = end


def _check_chunks(f: BinaryIO, size: int, path: Path) -> None:
    for pos, length in _chunks(f, size):
        f.seek(pos + _RECORD.size)
        head = f.read(_CHUNK.size)
        crc = _CHUNK.unpack(head)[3]
        if not crc:
            continue                            # not computed: nothing to check
        got = _records_crc(head + f.read(length - _CHUNK.size), pos, path)
        if got is not None and got != crc:
            raise _corrupt(path, f"mcap chunk at byte {pos} fails its CRC-32 check (stored "
                           f"0x{crc:08x}, computed 0x{got:08x})")


def _records_crc(body: bytes, pos: int, path: Path) -> Optional[int]:
    """The CRC-32 of a chunk's uncompressed records; ``None`` when it cannot be computed here
    (a malformed length or an unknown compression, which the reader names, or no library)."""
    uncompressed_size = _CHUNK.unpack_from(body, 0)[2]
    name_len, = struct.unpack_from("<I", body, _CHUNK.size)
    at = _CHUNK.size + 4 + name_len
    if at + 8 > len(body):
        return None
    compression = body[_CHUNK.size + 4:at].decode("utf-8", "replace")
    data_len, = struct.unpack_from("<Q", body, at)
    data = body[at + 8:at + 8 + data_len]
    factory = DECOMPRESSORS.get(compression)
    if factory is None or len(data) != data_len:
        return None
    try:
        decompress = factory()
    except ImportError:
        return None
    try:
        return zlib.crc32(decompress(data, uncompressed_size))
    except Exception as exc:                    # noqa: BLE001 - each library raises its own
        raise _corrupt(path, f"mcap chunk at byte {pos} cannot be decompressed "
                       f"({compression}: {type(exc).__name__}: {exc})") from None


def _footer(f: BinaryIO, size: int) -> Optional[tuple[int, int, int]]:
    """``(footer offset, summary_start, summary_crc)``, or ``None`` without a valid footer
    (cut short: the reader says so) or a summary."""
    footer_at = size - len(MAGIC) - _FOOTER.size
    if footer_at < len(MAGIC):
        return None
    f.seek(footer_at)
    raw = f.read(_FOOTER.size)
    if f.read(len(MAGIC)) != MAGIC:
        return None
    op, length, start, _, crc = _FOOTER.unpack(raw)
    if op != OP_FOOTER or length != _FOOTER.size - _RECORD.size or not start \
            or not len(MAGIC) <= start <= footer_at:
        return None
    return footer_at, start, crc


def _summary_crc(f: BinaryIO, footer_at: int, start: int) -> Optional[int]:
    return _crc_of(f, start, footer_at + _FOOTER.size - 4)     # through summary_offset_start


def _check_summary(f: BinaryIO, size: int, path: Path) -> None:
    footer = _footer(f, size)
    if footer is None or not footer[2]:
        return
    footer_at, start, crc = footer
    got = _summary_crc(f, footer_at, start)
    if got is not None and got != crc:
        raise _corrupt(path, f"mcap summary (from byte {start}) fails its CRC-32 check "
                       f"(stored 0x{crc:08x}, computed 0x{got:08x})")


def write_crcs(path: Path) -> None:
    """Write the CRC-32 of every chunk whose CRC is 0 and of the summary into an mcap file,
    in place (no size changes), as rosbag2's mcap writer computes them: the CRCs rosbags' writer
    leaves out, so that :func:`check_mcap` can check a bag this package wrote."""
    with path.open("r+b") as f:
        size = f.seek(0, 2)
        f.seek(0)
        if f.read(len(MAGIC)) != MAGIC:
            raise ValueError(f"{path}: not an mcap file")
        for pos, length in _chunks(f, size):
            f.seek(pos + _RECORD.size)
            body = f.read(length)
            if _CHUNK.unpack_from(body, 0)[3]:
                continue
            crc = _records_crc(body, pos, path)
            if crc is not None:
                f.seek(pos + _RECORD.size + _CHUNK.size - 4)
                f.write(struct.pack("<I", crc))
        footer = _footer(f, size)
        if footer is not None:
            footer_at, start, _ = footer
            crc = _summary_crc(f, footer_at, start)
            if crc is not None:
                f.seek(footer_at + _FOOTER.size - 4)
                f.write(struct.pack("<I", crc))


def _crc_of(f: BinaryIO, start: int, stop: int) -> Optional[int]:
    f.seek(start)
    crc, left = 0, stop - start
    while left > 0:
        block = f.read(min(left, _BLOCK))
        if not block:
            return None
        crc = zlib.crc32(block, crc)
        left -= len(block)
    return crc
