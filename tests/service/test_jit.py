"""service/jit.py: a leaf module without import-time side effects; the compiled-kernel cache folder is
chosen at start-up, only when this user owns it and nobody else can write it; a corrupt cache index does
not fail the warm-up; no per-start temporary folders."""

from __future__ import annotations

import ast
import json
import os
import shutil
import stat
import subprocess
import sys
from pathlib import Path

import pytest

from tests.helpers import ROOT, require

SERVICE_DIR = ROOT / "service"
_OURS = ("ADSM_NUMBA_CACHE_DIR", "NUMBA_CACHE_DIR", "XDG_CACHE_HOME", "TMPDIR")


def _python(code: str, **env: str) -> subprocess.CompletedProcess:
    environment = {key: value for key, value in os.environ.items() if key not in _OURS}
    environment.setdefault("PYTHONPATH", str(ROOT))
    completed = subprocess.run(
        [sys.executable, "-c", code], env={**environment, **env}, capture_output=True, text=True, timeout=600
    )
    assert completed.returncode == 0, completed.stderr
    return completed


def test_jit_is_a_leaf_module() -> None:
    tree = ast.parse((SERVICE_DIR / "jit.py").read_text(encoding="utf-8"))
    imported = {alias.name for node in ast.walk(tree) if isinstance(node, ast.Import) for alias in node.names}
    imported |= {node.module or "" for node in ast.walk(tree) if isinstance(node, ast.ImportFrom)}
    assert not [name for name in imported if name.split(".")[0] == "service"], imported


def test_importing_the_runtime_changes_nothing_in_the_host_process(tmp_path: Path) -> None:
    code = (
        "import json, os, numba; before = dict(os.environ); cache = numba.config.CACHE_DIR; "
        "import service.jit, service.matcher, service.cost.volume, service.optimization.sgm, "
        "service.disparity.wta, service.refinement.subpixel, service.validation.inner_check, "
        "service.filling.rays; "
        "print(json.dumps([dict(os.environ) == before, numba.config.CACHE_DIR == cache, "
        "service.jit.is_configured()]))"
    )
    out = _python(code, ADSM_NUMBA_CACHE_DIR=str(tmp_path / "cache")).stdout
    assert json.loads(out) == [True, True, False]
    assert not (tmp_path / "cache").exists()  # nothing chosen, nothing created at import


def test_jit_cache_works_from_a_read_only_package(tmp_path: Path) -> None:
    site = tmp_path / "site"
    package = site / "service"
    shutil.copytree(SERVICE_DIR, package, ignore=shutil.ignore_patterns("__pycache__", "models"))
    folders = [package, *(path for path in package.rglob("*") if path.is_dir())]
    for folder in folders:
        folder.chmod(stat.S_IRUSR | stat.S_IXUSR)
    cache = tmp_path / "numba-cache"
    code = (
        "import numpy as np, os; from service import jit; from service.optimization import aggregate; "
        "print(jit.configure_cache()); aggregate(np.ones((2, 3, 4), np.int16), p1=1.0, p2=2.0); "
        "assert 'NUMBA_CACHE_DIR' not in os.environ"
    )
    try:
        printed = _python(
            code, ADSM_NUMBA_CACHE_DIR=str(cache), PYTHONPATH=str(site), PYTHONDONTWRITEBYTECODE="1"
        ).stdout.strip()
    finally:
        for folder in folders:
            folder.chmod(stat.S_IRWXU)
    assert Path(printed) == cache.resolve()
    assert stat.S_IMODE(cache.stat().st_mode) == 0o700  # created private
    assert any(cache.rglob("*.nbi")) and any(cache.rglob("*.nbc"))  # index and compiled code
    assert not any(package.rglob("*.nb*"))


_CONFIGURE = "import logging; logging.basicConfig(); from service import jit; print(jit.configure_cache())"


def test_cache_dir_falls_back_with_a_log_line_and_leaves_no_folder_per_start(tmp_path: Path) -> None:
    blocker = tmp_path / "a-file"
    blocker.write_text("not a folder")
    fallback = tmp_path / "numba"
    done = _python(_CONFIGURE, ADSM_NUMBA_CACHE_DIR=str(blocker / "cache"), NUMBA_CACHE_DIR=str(fallback))
    assert Path(done.stdout.strip()) == fallback.resolve()
    assert f"{blocker / 'cache'}" in done.stderr and "cannot be created" in done.stderr  # logged, not dropped
    # Nothing usable from the environment or the home folder: one fixed folder per user in TMPDIR,
    # the same at every start.
    temporary = tmp_path / "tmp"
    temporary.mkdir()
    env = {"ADSM_NUMBA_CACHE_DIR": str(blocker / "a"), "XDG_CACHE_HOME": str(blocker),
           "TMPDIR": str(temporary)}
    first = Path(_python(_CONFIGURE, **env).stdout.strip())
    second = Path(_python(_CONFIGURE, **env).stdout.strip())
    assert first == second == (temporary / f"adsm-numba-{os.geteuid()}").resolve()
    assert [path.name for path in temporary.iterdir()] == [first.name]


@pytest.mark.parametrize("fault", ["world-writable folder", "group-writable file inside", "symlinked file",
                                   "foreign owner"])
def test_untrusted_cache_dirs_are_refused_with_a_log_line(tmp_path: Path, fault: str) -> None:
    untrusted = tmp_path / "planted"
    untrusted.mkdir(mode=0o700)
    planted = untrusted / "sgm_x" / "sgm.aggregate-100.py311.nbi"
    planted.parent.mkdir(mode=0o700)
    planted.write_bytes(b"not an index")
    planted.chmod(0o644)
    if fault == "world-writable folder":
        untrusted.chmod(0o777)
    elif fault == "group-writable file inside":
        planted.chmod(0o664)
    elif fault == "symlinked file":
        (planted.parent / "link.nbc").symlink_to(planted)
    else:
        require(os.geteuid() == 0, "root, to give a folder a foreign owner")
        os.chown(untrusted, 12345, 12345)
    fallback = tmp_path / "fallback"
    done = _python(_CONFIGURE, ADSM_NUMBA_CACHE_DIR=str(untrusted), NUMBA_CACHE_DIR=str(fallback))
    assert Path(done.stdout.strip()) == fallback.resolve()
    assert "refused" in done.stderr and str(untrusted) in done.stderr, done.stderr


@pytest.mark.slow
def test_a_corrupt_cache_index_is_cleared_and_warm_up_succeeds(tmp_path: Path) -> None:
    cache = tmp_path / "cache"
    code = (
        "import logging; logging.basicConfig(); from service import jit; jit.configure_cache(); "
        "from service.matcher import Matcher; Matcher.from_folder().warmup(); print('warm')"
    )
    _python(code, ADSM_NUMBA_CACHE_DIR=str(cache))  # fills the cache
    indexes = list(cache.rglob("*.nbi"))
    assert indexes
    for index in indexes:
        index.write_bytes(b"\x80\x04garbage")  # what a crash mid-write or a bad copy leaves
    done = _python(code, ADSM_NUMBA_CACHE_DIR=str(cache))
    assert done.stdout.strip() == "warm" and "unreadable" in done.stderr and "cleared" in done.stderr
    again = _python(code, ADSM_NUMBA_CACHE_DIR=str(cache))  # the next start finds a sound cache
    assert again.stdout.strip() == "warm" and "unreadable" not in again.stderr, again.stderr


def test_entrypoint_seeds_a_fresh_private_copy_at_every_start(tmp_path: Path) -> None:
    seed = tmp_path / "seed"
    (seed / "sgm_x").mkdir(parents=True)
    (seed / "sgm_x" / "k.nbi").write_bytes(b"good index")
    cache = tmp_path / "cache"
    env = {"PATH": os.environ["PATH"], "ADSM_NUMBA_CACHE_SEED": str(seed), "ADSM_NUMBA_CACHE_DIR": str(cache)}
    argv = ["sh", str(ROOT / "docker" / "entrypoint.sh"), "sh", "-c", 'echo "$ADSM_NUMBA_CACHE_DIR"']

    def start() -> str:
        done = subprocess.run(argv, env=env, capture_output=True, text=True, timeout=60, check=True)
        return done.stdout.strip()

    assert start() == str(cache)
    assert (cache / "sgm_x" / "k.nbi").read_bytes() == b"good index"
    # A corrupt or planted copy, a permissive mode and the old `.seeded` marker do not survive a restart.
    (cache / "sgm_x" / "k.nbi").write_bytes(b"corrupt")
    (cache / "sgm_x" / "planted.nbi").write_bytes(b"planted")
    (cache / ".seeded").touch()
    cache.chmod(0o777)
    assert start() == str(cache)
    assert sorted(path.name for path in cache.rglob("*")) == ["k.nbi", "sgm_x"]
    assert (cache / "sgm_x" / "k.nbi").read_bytes() == b"good index"
    assert stat.S_IMODE(cache.stat().st_mode) == 0o700
    assert not any(stat.S_IMODE(path.stat().st_mode) & 0o022 for path in cache.rglob("*"))
    # Without ADSM_NUMBA_CACHE_DIR: one fixed folder per user under TMPDIR, not a new one per start.
    del env["ADSM_NUMBA_CACHE_DIR"]
    env["TMPDIR"] = str(tmp_path / "tmp")
    (tmp_path / "tmp").mkdir()
    assert start() == start() == str(tmp_path / "tmp" / f"adsm-numba-{os.geteuid()}")
    assert len(list((tmp_path / "tmp").iterdir())) == 1
