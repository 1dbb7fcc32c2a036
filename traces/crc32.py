"""CRC-32 of a concatenation from the CRCs of its parts (zlib's ``crc32_combine``).

The MCAP data-section CRC runs over every byte of the file's data section, chunks
included; a chunk's own CRC (of its records) is computed anyway, so when the chunk is
written uncompressed the data-section CRC can take it up by combination (a few
microseconds) instead of a second pass over the bytes (about 0.2 ms per MB here).
``zlib.crc32`` has no combine; the zlib library Python's ``zlib`` module links does,
and :func:`crc32_combine` calls it through :mod:`ctypes`. Where that library cannot be
loaded (a Python with zlib built in statically), :data:`AVAILABLE` is False and callers
run the second pass.
"""

from __future__ import annotations

import ctypes
import sys
from typing import Any

__all__ = ["AVAILABLE", "crc32_combine"]


def _load() -> Any:
    names = ["libz.so.1", "libz.dylib", "libz.1.dylib"]
    found = None
    if sys.platform != "win32":
        for name in names:
            try:
                found = ctypes.CDLL(name)
                break
            except OSError:
                continue
        if found is None:
            from ctypes import util  # (imports subprocess: only when the names fail)

            path = util.find_library("z")
            if path:
                try:
                    found = ctypes.CDLL(path)
                except OSError:
                    found = None
    if found is None:
        return None
    function = getattr(found, "crc32_combine64", None) or getattr(found, "crc32_combine",
                                                                  None)
    if function is None:
        return None
    function.argtypes = (ctypes.c_ulong, ctypes.c_ulong, ctypes.c_int64)
    function.restype = ctypes.c_ulong
    # the binding must agree with zlib.crc32 (argument widths differ between builds)
    import zlib

    a, b = b"netsim", b"combine" * 40
    try:
        if function(zlib.crc32(a), zlib.crc32(b), len(b)) & 0xFFFFFFFF != zlib.crc32(a + b):
            return None
    except (OSError, ctypes.ArgumentError):  # pragma: no cover - a foreign build
        return None
    return function


_COMBINE = _load()

#: Whether :func:`crc32_combine` can be used (else it raises).
AVAILABLE = _COMBINE is not None


def crc32_combine(crc1: int, crc2: int, length2: int) -> int:
    """The CRC-32 of ``A + B`` from ``crc1 = crc32(A)``, ``crc2 = crc32(B)`` and
    ``length2 = len(B)``.

    Raises
    ------
    RuntimeError
        When no zlib library could be loaded (:data:`AVAILABLE` is False).

    Example
    -------
    >>> import zlib
    >>> a, b = b"state ", b"estimate"
    >>> crc32_combine(zlib.crc32(a), zlib.crc32(b), len(b)) == zlib.crc32(a + b)
    True
    """
    if _COMBINE is None:
        raise RuntimeError("crc32_combine: no zlib library to call (use zlib.crc32)")
    return int(_COMBINE(crc1, crc2, length2)) & 0xFFFFFFFF
