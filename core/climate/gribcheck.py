"""A structural check of GRIB files before ecCodes parses them.

ecCodes trusts the lengths in a message: a GRIB2 section claiming more bytes
than its message holds made cfgrib crash the whole process (a segmentation
fault, found by the readers' fuzz test), and a grid claiming billions of
points makes it allocate them.  :func:`check_grib` walks the messages with
plain seeks (a few reads per message, no decoding): every message must end in
``7777`` inside the file, every GRIB2 section must lie inside its message, and
the points a grid claims must fit in memory (:func:`~nephele.core.memory.check_memory`).

References
----------
.. [1] WMO Manual on Codes, Volume I.2, FM 92 GRIB edition 2 (sections 0-8).
"""

from ..errors import DataError
from ..memory import check_memory

_CHUNK = 1 << 20


def _next_message(f, pos, size):
    """Offset of the next ``GRIB`` at or after ``pos`` (ecCodes skips bytes between messages), or None."""
    f.seek(pos)
    carry = b""
    while pos < size:
        block = f.read(_CHUNK)
        if not block:
            return None
        data = carry + block
        i = data.find(b"GRIB")
        if i >= 0:
            return pos - len(carry) + i
        carry = data[-3:]
        pos += len(block)
    return None


def _sections(f, path, n, start, end):
    """Walk GRIB2 sections 1-7 of the message ``[start, end)``; the most values a field claims (section 3's
    number of data points, section 5's number of packed values)."""
    pos, points = start + 16, 0
    while True:
        f.seek(pos)
        head = f.read(5)
        if head[:4] == b"7777":
            if pos + 4 != end:
                raise DataError(f"cannot open as GRIB (message {n} at byte {start} ends before its stated length)", path=path)
            return points
        if len(head) < 5:
            break
        length, number = int.from_bytes(head[:4], "big"), head[4]
        if not 1 <= number <= 7 or length < 5 or pos + length > end - 4:
            raise DataError(f"cannot open as GRIB (message {n} at byte {start} is damaged: section {number} at byte {pos} "
                            f"claims {length} bytes, the message has {end - pos - 4} left)", path=path)
        if number in (3, 5):  # the grid's number of data points; the packed number of values (ecCodes decodes that many)
            want = 5 if number == 3 else 4
            body = f.read(want)
            if len(body) == want:
                points = max(points, int.from_bytes(body[-4:], "big"))
        pos += length
    raise DataError(f"cannot open as GRIB (message {n} at byte {start} has no end marker 7777)", path=path)


def check_grib(path):
    """Raise :class:`~nephele.core.errors.DataError` unless every message of ``path`` is whole.

    Returns the number of messages.
    """
    with open(path, "rb") as f:
        f.seek(0, 2)
        size = f.tell()
        pos, n, points = 0, 0, 0
        while True:
            start = _next_message(f, pos, size)
            if start is None:
                break
            n += 1
            f.seek(start)
            head = f.read(16)
            if len(head) < 8:
                raise DataError(f"cannot open as GRIB (message {n} at byte {start} is cut short)", path=path)
            edition = head[7]
            if edition == 1 and head[4] & 0x80:
                break  # a GRIB1 message over 8 MB states its length in units of 120 bytes: ecCodes walks on
            if edition == 2:
                length = int.from_bytes(head[8:16], "big")
            elif edition == 1:
                length = int.from_bytes(head[4:7], "big")
            else:
                raise DataError(f"cannot open as GRIB (message {n} at byte {start} has edition {edition}, not 1 or 2)", path=path)
            end = start + length
            if length < 20 or end > size:
                raise DataError(f"cannot open as GRIB (message {n} at byte {start} claims {length} bytes; "
                                f"the file has {size - start} left: truncated?)", path=path)
            if edition == 2:
                points = max(points, _sections(f, path, n, start, end))
            else:
                f.seek(end - 4)
                if f.read(4) != b"7777":
                    raise DataError(f"cannot open as GRIB (message {n} at byte {start} has no end marker 7777)", path=path)
            pos = end
    if n == 0:
        raise DataError("cannot open as GRIB (no GRIB message in the file)", path=path)
    # Decoding a field holds its values as float64, and cfgrib a copy.
    check_memory(16 * points, f"a GRIB grid of {points:,} points", path=path, field="number of values",
                 hint="the file claims more points than this machine can hold (damaged?)")
    return n


__all__ = ["check_grib"]
