"""Where numba's compiled kernels go (uvd/_jitcache.py): keyed on every kernel module, and
somewhere writable even when the install tree and the home directory are not (systemd's
ProtectSystem=strict, ProtectHome=yes), where numba's default refuses to import."""

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from uvd import _jitcache

ROOT = Path(__file__).resolve().parents[1]


def _tree(tmp_path):
    for pkg in ("uvd", "drivers", "sim_bridge"):
        (tmp_path / pkg).mkdir(parents=True)
    (tmp_path / "uvd" / "kern.py").write_text("import numba\n")
    (tmp_path / "uvd" / "plain.py").write_text("x = 1\n")
    return tmp_path


def test_the_key_follows_the_kernel_modules_only(tmp_path):
    root = _tree(tmp_path)
    k0 = _jitcache.source_key(root)
    (root / "uvd" / "plain.py").write_text("x = 2\n")
    assert _jitcache.source_key(root) == k0
    (root / "uvd" / "kern.py").write_text("import numba\n# edited\n")
    k1 = _jitcache.source_key(root)
    assert k1 != k0
    (root / "sim_bridge" / "new.py").write_text("from numba import njit\n")
    assert _jitcache.source_key(root) not in (k0, k1)


def test_configure_prefers_systemds_cache_directory_and_respects_the_users_choice(tmp_path):
    root = _tree(tmp_path / "src")
    env = {"CACHE_DIRECTORY": str(tmp_path / "cache"), "HOME": str(tmp_path / "home")}
    got = _jitcache.configure(root, env)
    assert got == tmp_path / "cache" / "numba" / _jitcache.source_key(root)
    assert env["NUMBA_CACHE_DIR"] == str(got) and got.is_dir()
    # a child process recomputes uvd's own choice (same tree: same place)
    assert _jitcache.configure(root, dict(env)) == got
    user = {"NUMBA_CACHE_DIR": str(tmp_path / "mine")}
    assert _jitcache.configure(root, user) is None
    assert user["NUMBA_CACHE_DIR"] == str(tmp_path / "mine")


def test_an_empty_cache_is_told_apart_from_a_filled_one(tmp_path):
    assert not _jitcache.cache_is_empty({})  # numba's default place: unknown, say nothing
    d = tmp_path / "numba" / "0123456789abcdef"
    assert _jitcache.cache_is_empty({"NUMBA_CACHE_DIR": str(d)})  # not even created yet
    (d / "uvd_0a1b").mkdir(parents=True)
    assert _jitcache.cache_is_empty({"NUMBA_CACHE_DIR": str(d)})
    (d / "uvd_0a1b" / "core._command-187.py311.nbi").write_bytes(b"")
    assert not _jitcache.cache_is_empty({"NUMBA_CACHE_DIR": str(d)})


def test_old_keys_are_pruned(tmp_path):
    root = _tree(tmp_path / "src")
    env = {"CACHE_DIRECTORY": str(tmp_path / "cache")}
    base = tmp_path / "cache" / "numba"
    for i in range(5):
        d = base / f"{i:016x}"
        d.mkdir(parents=True)
        os.utime(d, (1000 + i, 1000 + i))
    got = _jitcache.configure(root, env)
    left = sorted(p.name for p in base.iterdir())
    assert got.name in left and len(left) == _jitcache.KEEP
    assert f"{4:016x}" in left and f"{3:016x}" in left and f"{0:016x}" not in left


def _read_only_import(tmp_path, extra_env):
    """Import the kernel modules and run one kernel with the source tree mounted read-only
    and an unwritable home, in a private mount namespace (needs root and unshare)."""
    if os.geteuid() != 0 or shutil.which("unshare") is None:
        pytest.skip("needs root and unshare for a read-only bind mount")
    env = {k: v for k, v in os.environ.items()
           if k not in ("NUMBA_CACHE_DIR", "UVD_NUMBA_CACHE_AUTO", "XDG_CACHE_HOME",
                        "CACHE_DIRECTORY")}
    env.update(HOME="/proc/uvd-no-home", TMPDIR=str(tmp_path), PYTHONPATH=str(ROOT),
               **extra_env)
    code = ("import os, numpy as np, uvd.core, sim_bridge.plant\n"
            "from uvd.model.spd import min_max_eig\n"
            "assert min_max_eig(np.eye(2)) == (1.0, 1.0)\n"
            "print(os.environ['NUMBA_CACHE_DIR'])\n")
    script = (f"mount --bind {ROOT} {ROOT} && mount -o remount,bind,ro {ROOT} && "
              f"exec {sys.executable} -c \"$UVD_CODE\"")
    env["UVD_CODE"] = code
    r = subprocess.run(["unshare", "-m", "sh", "-c", script], env=env, cwd=tmp_path,
                       capture_output=True, text=True, timeout=300)
    if r.returncode != 0 and "mount" in r.stderr and "uvd" not in r.stderr:
        pytest.skip(f"no read-only bind mount here: {r.stderr.strip()[:200]}")
    assert r.returncode == 0, r.stderr[-3000:]
    cache = Path(r.stdout.strip().splitlines()[-1])
    assert any(cache.rglob("*.nbi")), f"nothing cached in {cache}"
    return cache


def test_a_read_only_install_without_a_home_imports_and_caches_in_the_temp_dir(tmp_path):
    cache = _read_only_import(tmp_path, {})
    assert cache.parent == tmp_path / f"uvd-numba-{os.getuid()}"


def test_under_systemd_the_kernels_go_to_the_cache_directory(tmp_path):
    cache = _read_only_import(tmp_path, {"CACHE_DIRECTORY": str(tmp_path / "var-cache-uvd")})
    assert cache.parent == tmp_path / "var-cache-uvd" / "numba"
