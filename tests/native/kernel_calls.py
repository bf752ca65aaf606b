"""Kernel calls recorded on Linux, written for native/tests/harness.c, and its results read back.

:class:`Recorder` stands in for :func:`nephele.core.native.kernel`: each kernel it hands out copies its
arguments' buffers before and after the real call (calls run one at a time while it records).  A
pointer argument is an array address (``x.ctypes.data``), an ``ndpointer`` array, a ctypes array of
addresses (a struct of pointers, ``blobby_march_*``) or a ctypes structure of 8-byte fields, passed
by ``byref`` (``scatter_sweep``'s ``struct nph_sweep``: addresses and integers); the arrays behind the
addresses are found among the calling frames' variables, so the calls must come from the thread that
made the arrays (one thread: ``OMP_NUM_THREADS=1``).  ``harness CALLS OUT`` then replays the calls on
any platform, and :func:`read_out` gives each call's result and buffers.
"""

import collections
import ctypes
import struct
import sys
import threading
import types

import numpy as np

# ctypes type -> harness kind (native/tests/kernels.def)
_KINDS = {ctypes.c_int64: "I64", ctypes.c_int32: "I32", ctypes.c_double: "F64", ctypes.c_float: "F32",
          ctypes.c_void_p: "P", None: "V"}


def kind(t):
    """The kernels.def kind of a ctypes argument or result type."""
    if t in _KINDS:
        return _KINDS[t]
    if isinstance(t, type) and (issubclass(t, ctypes._Pointer) or hasattr(t, "_dtype_")):  # POINTER, ndpointer
        return "P"
    raise TypeError(f"no harness kind for {t!r}")


def _words(obj):
    """A ctypes array or structure of 8-byte fields as words: ("p", address or None) or ("i", integer)."""
    if isinstance(obj, ctypes.Array):
        items = [(obj._type_, v) for v in obj]
    else:
        items = [(t, getattr(obj, name)) for name, t in obj._fields_]
    out = []
    for t, v in items:
        if issubclass(t, ctypes.Array):
            out += _words(v)
        elif ctypes.sizeof(t) != 8:
            raise TypeError(f"harness tables hold 8-byte words, not {t.__name__}")
        elif kind(t) == "P":
            out.append(("p", v if v is None or isinstance(v, int) else ctypes.cast(v, ctypes.c_void_p).value))
        else:
            out.append(("i", int(v)))
    return out


class Call:
    """One recorded call: buffers before and after, the arguments referring to them, the result."""

    def __init__(self, name, sig):
        self.name, self.sig = name, sig
        self.before, self.after, self.tables, self.args, self.result = [], [], {}, [], 0


def _arrays(obj, depth=2):
    if isinstance(obj, np.ndarray):
        yield obj
        if isinstance(obj.base, np.ndarray):
            yield obj.base
    elif depth and isinstance(obj, (list, tuple)):
        for x in obj:
            yield from _arrays(x, depth - 1)
    elif depth and isinstance(obj, dict):
        for x in obj.values():
            yield from _arrays(x, depth - 1)


def _frame_arrays(frames=4):
    """Arrays the calling frames hold (locals, closures, lists, tuples, dicts of them)."""
    f, found = sys._getframe(2), []
    for _ in range(frames):
        if f is None:
            break
        for v in list(f.f_locals.values()):
            found += [a for a in _arrays(v) if a.flags.c_contiguous]
        f = f.f_back
    return found


class Recorder:
    """Records the first ``limit`` calls of each kernel, or of each of its paths where ``paths[name]``
    says which path a call takes (a function of the call's arguments); ``kernel`` replaces
    :func:`native.kernel`."""

    def __init__(self, real_kernel, limit=2, paths=None):
        self.real, self.limit, self.paths = real_kernel, limit, paths or {}
        self.calls, self.counts, self.lock = [], collections.Counter(), threading.Lock()

    def kernel(self, name, restype, argtypes):
        fn = self.real(name, restype, argtypes)
        if fn is None:
            return None
        sig = (kind(restype), tuple(kind(t) for t in argtypes))

        def call(*args):
            with self.lock:
                path = (name, self.paths[name](*args) if name in self.paths else None)
                if self.counts[path] >= self.limit:
                    return fn(*args)
                self.counts[path] += 1
                rec = Call(name, sig)
                views = self._resolve(rec, args, _frame_arrays())
                rec.before = [v.tobytes() for v in views]
                rec.result = fn(*args)
                rec.after = [v.tobytes() for v in views]
                self.calls.append(rec)
                return rec.result

        return call

    def _resolve(self, rec, args, arrays):
        views, where = [], {}

        def buffer(addr):
            if addr is None:
                return -1
            if addr not in where:
                hits = [a for a in arrays if a.ctypes.data <= addr < a.ctypes.data + max(a.nbytes, 1)]
                if not hits:
                    raise LookupError(f"{rec.name}: no array in the calling frames holds address {addr:#x}")
                a = max(hits, key=lambda a: a.nbytes)
                flat = a.reshape(-1).view(np.uint8)
                where[addr] = len(views)
                views.append(flat[addr - a.ctypes.data :])
            return where[addr]

        for x in args:
            obj = getattr(x, "_obj", None) if type(x).__name__ == "CArgObject" else x  # byref(struct)
            if isinstance(x, np.ndarray):
                arrays.append(x)
                rec.args.append(("p", buffer(x.ctypes.data)))
            elif isinstance(obj, (ctypes.Array, ctypes.Structure)):  # a struct: a table buffer
                words = [(k, buffer(v) if k == "p" else v) for k, v in _words(obj)]
                if 8 * len(words) != ctypes.sizeof(obj):
                    raise TypeError(f"{rec.name}: a struct argument must be all 8-byte fields")
                rec.tables[len(views)] = words
                views.append(np.zeros(0, np.uint8))
                rec.args.append(("p", len(views) - 1))
            elif isinstance(x, (float, np.floating)):
                rec.args.append(("d", float(x)))
            elif x is None:
                rec.args.append(("p", -1))
            elif rec.sig[1][len(rec.args)] == "P":
                rec.args.append(("p", buffer(int(x))))
            else:
                rec.args.append(("i", int(x)))
        return views


def write_calls(calls, path):
    """CALLS.bin for harness.c (format in its header comment)."""
    out = [b"NPHCALL1", struct.pack("<I", len(calls))]
    for c in calls:
        name = c.name.encode()
        out += [struct.pack("<I", len(name)), name, struct.pack("<I", len(c.before))]
        for i, data in enumerate(c.before):
            if i in c.tables:
                out.append(struct.pack("<cI", b"t", len(c.tables[i])))
                out += [struct.pack("<ci" if k == "p" else "<cq", k.encode(), v) for k, v in c.tables[i]]
            else:
                out += [struct.pack("<cQ", b"b", len(data)), data]
        out.append(struct.pack("<I", len(c.args)))
        for k, v in c.args:
            out.append(struct.pack({"i": "<cq", "d": "<cd", "p": "<ci"}[k], k.encode(), v))
    path.write_bytes(b"".join(out))


def read_out(path):
    """[(result, [buffer bytes, ...]), ...] from a harness OUT.bin."""
    data = path.read_bytes()
    if data[:8] != b"NPHOUT01":
        raise ValueError(f"{path}: not a harness output")
    (n,), o, calls = struct.unpack_from("<I", data, 8), 12, []
    for _ in range(n):
        result, nbuf = struct.unpack_from("<qI", data, o)
        o += 12
        bufs = []
        for _ in range(nbuf):
            (size,) = struct.unpack_from("<Q", data, o)
            bufs.append(data[o + 8 : o + 8 + size])
            o += 8 + size
        calls.append((result, bufs))
    if o != len(data):
        raise ValueError(f"{path}: {len(data) - o} bytes left over")
    return calls


def loaded(lib_path):
    """A stand-in for the nephele_native module that loads ``lib_path`` (``native._module``'s result)."""
    build_id = lib_path.with_name("BUILD_ID").read_text().strip()
    return types.SimpleNamespace(lib=ctypes.CDLL(str(lib_path)), BUILD_ID=build_id)
