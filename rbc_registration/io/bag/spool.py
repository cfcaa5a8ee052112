"""The node's inputs read from a bag, held as fixed-width binary records in an unlinked
temporary file (:class:`InputSpool`) instead of Python objects: memory flat in the messages.

A spool reads back as the :class:`~rbc_registration.pipeline.inputs.PairMessage` and
:class:`~rbc_registration.pipeline.inputs.PointMessage` tuples it was given, equal field by field
(floats bit for bit, NaN included), in order, as often as it is iterated; texts (ids, frames,
groups, sessions, stamp errors) are stored once each.
"""

from __future__ import annotations

import tempfile
from typing import IO, Any, Iterator, Union

import numpy as np

from ...pipeline.inputs import PairMessage, PointMessage

Input = Union[PairMessage, PointMessage]

#: One record: the kind (0 a pair, 1 a point), the receive time, the stamp (seconds, and
#: nanoseconds with whether it is given), the working and destination points (a point
#: message: its point first), and the texts' numbers.
RECORD = np.dtype([("kind", "u1"), ("has_ns", "u1"), ("log_ns", "i8"), ("stamp_s", "f8"),
                   ("stamp_ns", "i8"), ("a", "f8", 3), ("b", "f8", 3), ("id", "u4"),
                   ("frame_a", "u4"), ("frame_b", "u4"), ("error", "u4"), ("group", "u4"),
                   ("session", "u4")])
#: Records buffered before a write (and read back at once).
CHUNK = 8192


class InputSpool:
    """A sequence of inputs on disk: :meth:`append` in order, then iterate (or index, or
    compare with a sequence) as with a tuple of them."""

    def __init__(self) -> None:
        self._file: IO[bytes] = tempfile.TemporaryFile(prefix="rbc-bag-")
        self._texts: dict[str, int] = {}
        self._names: list[str] = []
        self._buffer: list[tuple[Any, ...]] = []
        self._rows = 0

    def _text(self, value: str) -> int:
        k = self._texts.get(value)
        if k is None:
            k = self._texts[value] = len(self._names)
            self._names.append(value)
        return k

    def append(self, m: Input) -> None:
        """Add the next input."""
        t = self._text
        if isinstance(m, PairMessage):
            ns = m.stamp_ns
            self._buffer.append((0, ns is not None, m.log_ns, m.stamp_s, ns or 0, m.working,
                                 m.destination, t(m.fiducial_id), t(m.working_frame),
                                 t(m.destination_frame), t(m.stamp_error), t(m.group),
                                 t(m.session)))
        else:
            self._buffer.append((1, False, m.log_ns, m.stamp_s, 0, m.xyz, (0.0, 0.0, 0.0),
                                 t(m.stream), t(m.frame_id), 0, t(m.stamp_error), 0, 0))
        self._rows += 1
        if len(self._buffer) >= CHUNK:
            self._flush()

    def _flush(self) -> None:
        if self._buffer:
            self._file.seek(0, 2)
            self._file.write(np.array(self._buffer, dtype=RECORD).tobytes())
            self._buffer = []

    def __len__(self) -> int:
        return self._rows

    def __iter__(self) -> Iterator[Input]:
        self._flush()
        names = self._names
        offset = 0
        size = CHUNK * RECORD.itemsize
        while True:
            self._file.seek(offset)
            data = self._file.read(size)
            if not data:
                return
            offset += len(data)
            rec = np.frombuffer(data, dtype=RECORD)
            cols = [rec[f].tolist() for f in ("kind", "has_ns", "log_ns", "stamp_s", "stamp_ns",
                                              "id", "frame_a", "frame_b", "error", "group",
                                              "session")]
            a, b = rec["a"].tolist(), rec["b"].tolist()
            for k, (kind, has_ns, log_ns, stamp_s, stamp_ns, i, fa, fb, err, grp,
                    ses) in enumerate(zip(*cols)):
                if kind == 0:
                    yield PairMessage(log_ns, stamp_s, names[i], tuple(a[k]), names[fa],
                                      tuple(b[k]), names[fb], stamp_ns if has_ns else None,
                                      names[err], names[grp], names[ses])
                else:
                    yield PointMessage(log_ns, names[i], tuple(a[k]), names[fa], stamp_s,
                                       names[err])

    def __getitem__(self, index: Union[int, slice]) -> Any:
        if isinstance(index, slice):
            return tuple(self)[index]
        n = len(self)
        k = index + n if index < 0 else index
        if not 0 <= k < n:
            raise IndexError("spool index out of range")
        for j, m in enumerate(self):
            if j == k:
                return m
        raise IndexError("spool index out of range")     # pragma: no cover

    def __eq__(self, other: object) -> bool:
        if isinstance(other, (InputSpool, tuple, list)):
            return len(self) == len(other) and all(a == b for a, b in zip(self, other))
        return NotImplemented

    __hash__ = None  # type: ignore[assignment]

    def __add__(self, other: Any) -> tuple:
        """``tuple(self) + other`` (the spool joins a tuple as the tuple it stands for)."""
        return tuple(self) + tuple(other)

    def __radd__(self, other: Any) -> tuple:
        return tuple(other) + tuple(self)

    def close(self) -> None:
        self._file.close()
