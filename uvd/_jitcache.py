"""Where numba keeps the compiled kernels (``cache=True``): chosen before numba is imported.

Two failures of numba's default, which keeps each module's kernels in the ``__pycache__``
beside it and keys them on that one file:

* **A read-only install does not start.** Under the systemd unit (``ProtectSystem=strict``,
  ``ProtectHome=yes``, a system user without a home) neither ``__pycache__`` nor ``~/.cache``
  is writable, and numba then refuses to import the module: ``RuntimeError: cannot cache
  function …: no locator available``.
* **Stale kernels after an edit.** A kernel that calls a kernel of another module keeps the
  callee it was compiled with until its *own* file changes (numba tracks no dependencies).

So, unless the user set ``NUMBA_CACHE_DIR``, uvd sets it to ``<base>/<key>``. ``key`` is a
hash of every source file of uvd, drivers and sim_bridge that mentions numba, so an edit to
any kernel module recompiles all the kernels (the daemon's first start: 34 s on the CI
machine, 1.2 s once cached). ``base`` is the first writable one of:

1. ``$CACHE_DIRECTORY/numba``, which systemd creates (``CacheDirectory=uvd`` in the unit);
2. ``uvd/__pycache__/numba`` in the source or install tree;
3. ``$XDG_CACHE_HOME/uvd/numba`` (default ``~/.cache/uvd/numba``);
4. ``<temp dir>/uvd-numba-<uid>``.

The older keys under ``base`` are removed; the newest :data:`KEEP` stay. Child processes
(sim-bridge, test subprocesses) inherit the variable.
"""

from __future__ import annotations

import hashlib
import os
import shutil
import sys
import tempfile
from pathlib import Path

KEEP = 3
_MARK = "UVD_NUMBA_CACHE_AUTO"  # set beside NUMBA_CACHE_DIR when uvd chose it
_PACKAGES = ("uvd", "drivers", "sim_bridge")


def source_key(root: Path) -> str:
    """Hash of the path and content of every ``*.py`` under ``root``/{uvd, drivers,
    sim_bridge} that mentions numba (16 hex digits)."""
    h = hashlib.sha256()
    for pkg in _PACKAGES:
        for path in sorted((root / pkg).rglob("*.py")):
            data = path.read_bytes()
            if b"numba" in data:
                h.update(path.relative_to(root).as_posix().encode())
                h.update(b"\0")
                h.update(hashlib.sha256(data).digest())
    return h.hexdigest()[:16]


def _writable_dir(path: Path) -> bool:
    try:
        path.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryFile(dir=path):
            pass
    except OSError:
        return False
    return True


def candidate_bases(root: Path, env: dict) -> list[Path]:
    """The bases in order of preference (see the module note)."""
    out = []
    if env.get("CACHE_DIRECTORY"):
        # systemd may list several, separated by ':'; the first is ours
        out.append(Path(env["CACHE_DIRECTORY"].split(":")[0]) / "numba")
    out.append(root / "uvd" / "__pycache__" / "numba")
    xdg = env.get("XDG_CACHE_HOME") or (str(Path(env["HOME"]) / ".cache")
                                         if env.get("HOME") else "")
    if xdg:
        out.append(Path(xdg) / "uvd" / "numba")
    uid = os.getuid() if hasattr(os, "getuid") else 0
    out.append(Path(tempfile.gettempdir()) / f"uvd-numba-{uid}")
    return out


def _prune(base: Path, keep_name: str) -> None:
    """Remove all but the newest :data:`KEEP` key directories under ``base``."""
    def mtime(d: Path) -> float:
        try:
            return d.stat().st_mtime
        except OSError:  # removed meanwhile by another process
            return 0.0

    try:
        dirs = [d for d in base.iterdir() if d.is_dir() and len(d.name) == 16]
    except OSError:
        return
    dirs.sort(key=mtime, reverse=True)
    for d in dirs[KEEP:]:
        if d.name != keep_name:
            shutil.rmtree(d, ignore_errors=True)


def configure(root: Path | None = None, env: dict | None = None) -> Path | None:
    """Set ``NUMBA_CACHE_DIR`` (in ``env``, default ``os.environ``) as the module note says;
    returns the directory, or None when the user's own ``NUMBA_CACHE_DIR`` stands or no
    candidate is writable (numba's default then applies)."""
    env = os.environ if env is None else env
    if env.get("NUMBA_CACHE_DIR") and env.get(_MARK) != "1":
        return None  # the user's choice
    root = Path(__file__).resolve().parent.parent if root is None else root
    try:
        key = source_key(root)
    except OSError:
        return None
    for base in candidate_bases(root, env):
        target = base / key
        if _writable_dir(target):
            os.utime(target)  # newest: kept by the pruning of other trees' processes
            _prune(base, key)
            env["NUMBA_CACHE_DIR"] = str(target)
            env[_MARK] = "1"
            numba_config = sys.modules.get("numba.core.config")
            if numba_config is not None and env is os.environ:
                numba_config.CACHE_DIR = str(target)  # numba came first: tell it directly
            return target
    return None


def cache_is_empty(env: dict | None = None) -> bool:
    """True when ``NUMBA_CACHE_DIR`` is set and holds no compiled kernel yet: the first run
    after an install, an upgrade or any edit of a kernel module compiles them (tens of
    seconds). False when unknown (numba's default location)."""
    d = (os.environ if env is None else env).get("NUMBA_CACHE_DIR")
    if not d:
        return False
    path = Path(d)
    return not (path.is_dir() and next(path.rglob("*.nbi"), None) is not None)
