"""The CRC-32 checks of an mcap file, made here so that they do not depend on the rosbags
version (rosbags 0.11.0, the lowest this package supports, checks none of them):

- every Chunk's CRC of its uncompressed records (rosbag2's mcap writer writes it by default);
- the Summary's CRC (the chunk indexes and statistics a reader goes by), over the bytes from
  the summary's start through the footer's ``summary_offset_start`` field.

A CRC of 0 means "not computed" (rosbags' own writer) and checks nothing. The data section's
optional CRC (off by default in rosbag2) is not checked. A file cut short is left to the reader,
which names how many messages it read: only complete records are checked here.
"""

from __future__ import annotations

import struct
import zlib
from pathlib import Path
from typing import BinaryIO, Callable, Optional

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


def mcap_files(path: Path) -> list[Path]:
    """The mcap files of a bag: ``path`` itself, or the ``.mcap`` files its ``metadata.yaml``
    lists (``relative_file_paths``; another file in the directory is not the bag's). A
    metadata file that cannot be read gives none: opening the bag then says what is wrong."""
    if not path.is_dir():
        return [path] if path.suffix == ".mcap" else []
    try:
        info = yaml.safe_load((path / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
        names = [str(name) for name in info["relative_file_paths"]]
    except (OSError, UnicodeDecodeError, yaml.YAMLError, KeyError, TypeError):
        return []
    return [path / name for name in names
            if name.endswith(".mcap") and (path / name).is_file()]


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


def _check_chunks(f: BinaryIO, size: int, path: Path) -> None:
    pos = len(MAGIC)
    while pos + _RECORD.size <= size:
        f.seek(pos)
        op, length = _RECORD.unpack(f.read(_RECORD.size))
        end = pos + _RECORD.size + length
        if op in (OP_DATA_END, OP_FOOTER) or end > size:
            return                              # the data section ends, or the file is cut
        if op == OP_CHUNK and length >= _CHUNK.size + 4:
            head = f.read(_CHUNK.size)
            if _CHUNK.unpack(head)[3]:          # a CRC to check: read the rest of the chunk
                _check_chunk(head + f.read(length - _CHUNK.size), pos, path)
        pos = end


def _check_chunk(body: bytes, pos: int, path: Path) -> None:
    _, _, uncompressed_size, crc = _CHUNK.unpack_from(body, 0)
    name_len, = struct.unpack_from("<I", body, _CHUNK.size)
    at = _CHUNK.size + 4 + name_len
    if at + 8 > len(body):
        return                                  # malformed: the reader names it
    compression = body[_CHUNK.size + 4:at].decode("utf-8", "replace")
    data_len, = struct.unpack_from("<Q", body, at)
    data = body[at + 8:at + 8 + data_len]
    factory = DECOMPRESSORS.get(compression)
    if factory is None or len(data) != data_len:
        return                                  # the reader names the compression or length
    try:
        decompress = factory()
    except ImportError:
        return                                  # no library for it here: the reader says so
    try:
        raw = decompress(data, uncompressed_size)
    except Exception as exc:                    # noqa: BLE001 - each library raises its own
        raise _corrupt(path, f"mcap chunk at byte {pos} cannot be decompressed "
                       f"({compression}: {type(exc).__name__}: {exc})") from None
    got = zlib.crc32(raw)
    if got != crc:
        raise _corrupt(path, f"mcap chunk at byte {pos} fails its CRC-32 check (stored "
                       f"0x{crc:08x}, computed 0x{got:08x})")


def _check_summary(f: BinaryIO, size: int, path: Path) -> None:
    footer_at = size - len(MAGIC) - _FOOTER.size
    if footer_at < len(MAGIC):
        return
    f.seek(footer_at)
    raw = f.read(_FOOTER.size)
    if f.read(len(MAGIC)) != MAGIC:
        return                                  # no footer (cut short): the reader says so
    op, length, start, _, crc = _FOOTER.unpack(raw)
    if op != OP_FOOTER or length != _FOOTER.size - _RECORD.size or not crc or not start:
        return
    stop = footer_at + _FOOTER.size - 4         # through summary_offset_start
    if not len(MAGIC) <= start <= footer_at:
        return
    got = _crc_of(f, start, stop)
    if got is not None and got != crc:
        raise _corrupt(path, f"mcap summary (from byte {start}) fails its CRC-32 check "
                       f"(stored 0x{crc:08x}, computed 0x{got:08x})")


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
