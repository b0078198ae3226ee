"""JSON output shared by every ``--json OUT`` option (OUT is always a file path), and the
one way a result file is written whole or not at all (:func:`write_whole`)."""

from __future__ import annotations

import json
import math
import os
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np


def to_jsonable(obj: Any) -> Any:
    """Convert numpy scalars/arrays (recursively) to plain Python; non-finite floats to None."""
    if isinstance(obj, np.ndarray):
        # fast path (a telemetry record is mostly small float arrays): one finiteness check
        # instead of a call per element
        if obj.dtype.kind in "iub" or (obj.dtype.kind == "f" and bool(np.isfinite(obj).all())):
            return obj.tolist()
        return to_jsonable(obj.tolist())
    if isinstance(obj, dict):
        return {str(k): to_jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [to_jsonable(v) for v in obj]
    if isinstance(obj, (np.floating, float)):
        f = float(obj)
        return f if math.isfinite(f) else None
    if isinstance(obj, (np.integer,)):
        return int(obj)
    if isinstance(obj, (np.bool_,)):
        return bool(obj)
    if isinstance(obj, Path):
        return str(obj)
    return obj


def write_json(path: Path, data: Any) -> None:
    """``data`` as indented JSON in ``path``, whole or not at all (a temporary file beside it,
    renamed); a write that fails (a full disk) leaves no temporary file and names the path."""
    path = Path(path)
    if path.exists() and path.is_dir():
        raise IsADirectoryError(f"--json takes a file path, and {path} is a folder")
    path.parent.mkdir(parents=True, exist_ok=True)
    text = json.dumps(to_jsonable(data), indent=2) + "\n"
    write_whole(path, lambda tmp: tmp.write_text(text), path.with_suffix(path.suffix + ".tmp"))


def write_whole(path: Path, write: Callable[[Path], Any], tmp: Path,
                what: str | None = None) -> None:
    """``write(tmp)``, then ``tmp`` renamed over ``path``: the file is whole or not there. A
    write that fails (a full disk) or is interrupted (Ctrl-C) leaves no temporary file; an
    OSError names ``what`` (``path`` by default). ``tmp``'s data is forced to the disk before
    the rename and the rename after it, so that a power cut of the machine too leaves the old
    file or the new one — not an empty one, which some file systems leave of a renamed file
    whose data was still in memory."""
    try:
        write(tmp)
        sync_to_disk(tmp)
        os.replace(tmp, path)
        sync_to_disk(path.parent)
    except OSError as exc:
        _discard(tmp)
        raise OSError(exc.errno, f"cannot write {what or path}: {exc.strerror or exc}") \
            from exc
    except BaseException:
        _discard(tmp)
        raise


def _discard(tmp: Path) -> None:
    """Remove a temporary file if there is one; a removal that fails (``tmp`` a folder that
    was there before, a folder without write permission) never hides the error that came
    first."""
    try:
        tmp.unlink(missing_ok=True)
    except OSError:
        pass


def sync_to_disk(path: Path) -> None:
    """A file's data, or a folder's entries (a new or renamed file's name), forced to the
    disk: what a power cut of the machine then keeps."""
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def is_int64(x: Any) -> bool:
    """``x`` is an integer a clock in ns can be (int64; JSON's ``true`` is not one): what a
    record's time stamp must be, wherever records are read."""
    return isinstance(x, int) and not isinstance(x, bool) and -2 ** 63 <= x < 2 ** 63
