"""A structural check of GRIB files before ecCodes parses them.

ecCodes trusts the lengths in a message: a GRIB2 section claiming more bytes
than its message holds made cfgrib crash the whole process (a segmentation
fault, found by the readers' fuzz test), and a grid claiming billions of
points makes it allocate them.  :func:`check_grib` walks the messages with
plain seeks (a few reads per message, no decoding): every section of a whole
message (GRIB2: sections 1-7; GRIB1: the PDS, GDS, BMS and BDS) must lie inside it,
and the points a grid claims must fit in memory
(:func:`~nephele.core.memory.check_memory`).  Messages cut short are left to the
reader, which skips them with a note and reads the rest.

References
----------
.. [1] WMO Manual on Codes, Volume I.2, FM 92 GRIB edition 2 (sections 0-8).
.. [2] WMO, "A guide to the code form FM 92-IX Ext. GRIB edition 1" (1994): sections 0-5.
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
                raise DataError(f"cannot open as GRIB (message {n} at byte {start} ends before its stated length)",
                                path=path)
            return points
        if len(head) < 5:
            break
        length, number = int.from_bytes(head[:4], "big"), head[4]
        if not 1 <= number <= 7 or length < 5 or pos + length > end - 4:
            raise DataError(f"cannot open as GRIB (message {n} at byte {start} is damaged: section {number} at byte "
                            f"{pos} claims {length} bytes, the message has {end - pos - 4} left)", path=path)
        if number in (3, 5):
            # the grid's number of data points; the packed number of values (ecCodes decodes that many)
            want = 5 if number == 3 else 4
            body = f.read(want)
            if len(body) == want:
                points = max(points, int.from_bytes(body[-4:], "big"))
        pos += length
    raise DataError(f"cannot open as GRIB (message {n} at byte {start} has no end marker 7777)", path=path)


def _sections1(f, path, n, start, end):
    """Walk a GRIB1 message's sections (PDS, the GDS and BMS its flags announce, BDS): each must lie inside
    ``[start, end)``; the points of a grid whose GDS gives Ni and Nj (0 when it does not)."""
    f.seek(start + 8)
    pds = f.read(8)
    if len(pds) < 8:
        return 0
    flags, pos, points = pds[7], start + 8, 0
    names = ["PDS"] + ["GDS"] * bool(flags & 0x80) + ["BMS"] * bool(flags & 0x40) + ["BDS"]
    for name in names:
        f.seek(pos)
        head = f.read(10)
        length = int.from_bytes(head[:3], "big") if len(head) >= 3 else 0
        if length < 3 or pos + length > end - 4:
            raise DataError(f"cannot open as GRIB (message {n} at byte {start} is damaged: its {name} at byte {pos} "
                            f"claims {length} bytes, the message has {end - pos - 4} left)", path=path)
        if name == "GDS" and len(head) == 10:
            ni, nj = int.from_bytes(head[6:8], "big"), int.from_bytes(head[8:10], "big")
            if 0xFFFF not in (ni, nj):  # (0xFFFF: a reduced grid, its rows listed further on)
                points = ni * nj
        pos += length
    return points


def check_grib(path):
    """Raise :class:`~nephele.core.errors.DataError` when a whole message of ``path`` would crash ecCodes.

    A message whose sections claim more bytes than it holds, or a grid of more
    points than memory holds, refuses the file.  What ecCodes skips safely is
    left to it (the reader skips it with a note): bytes that only spell
    ``GRIB``, a message cut short by the end of the file or missing its ``7777``.
    Returns the number of whole messages.
    """
    with open(path, "rb") as f:
        f.seek(0, 2)
        size = f.tell()
        pos, n, points = 0, 0, 0
        while True:
            start = _next_message(f, pos, size)
            if start is None:
                break
            pos = start + 4  # unless this is a whole message: then past it
            f.seek(start)
            head = f.read(16)
            edition = head[7] if len(head) >= 8 else 0
            if edition == 1 and head[4] & 0x80:
                break  # a GRIB1 message over 8 MB states its length in units of 120 bytes: ecCodes walks on
            if edition == 2 and len(head) == 16:
                length = int.from_bytes(head[8:16], "big")
            elif edition == 1:
                length = int.from_bytes(head[4:7], "big")
            else:
                continue  # not a message (or cut short before its length)
            end = start + length
            if length < 20 or end > size:
                continue  # cut short: ecCodes skips it
            f.seek(end - 4)
            if f.read(4) != b"7777":
                continue
            walk = _sections if edition == 2 else _sections1
            points = max(points, walk(f, path, n + 1, start, end))
            n += 1
            pos = end
    # Decoding a field holds its values as float64, and the reader a copy.
    check_memory(16 * points, f"a GRIB grid of {points:,} points", path=path, field="number of values",
                 hint="the file claims more points than this machine can hold (damaged?)")
    return n


__all__ = ["check_grib"]
