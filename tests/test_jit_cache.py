"""mapper.jit: one kernel cache per version of the mapper's sources (numba alone checks a cached
kernel only against its own file, so a kernel calling another module's kernel went stale)."""

from __future__ import annotations

import shutil
from pathlib import Path

import numba

import mapper
from mapper.jit import cache_dir, prune_caches

PACKAGE = Path(mapper.__file__).resolve().parent


def test_the_cache_follows_every_source_file(tmp_path, monkeypatch):
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path / "cache"))
    copy = tmp_path / "mapper"
    copy.mkdir()
    for f in PACKAGE.glob("*.py"):
        shutil.copy(f, copy / f.name)
    same = cache_dir(copy)
    assert same == cache_dir(PACKAGE)
    assert same.parent == tmp_path / "cache" and same.name.startswith("asrmap-")
    # a change in a callee's module alone (exits.py holds closest_point, which asr_builder's
    # compiled pair search calls) moves every kernel to a new cache
    (copy / "exits.py").write_text((copy / "exits.py").read_text() + "\n# changed\n")
    assert cache_dir(copy) != same
    assert cache_dir(copy).parent == same.parent


def test_without_numba_cache_dir_the_user_cache_is_used(tmp_path, monkeypatch):
    monkeypatch.delenv("NUMBA_CACHE_DIR", raising=False)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    assert cache_dir().parent == tmp_path / "asrmap" / "numba"


def test_numba_was_pointed_at_this_versions_cache():
    assert Path(numba.config.CACHE_DIR) == cache_dir()
    assert cache_dir().is_dir()


def test_only_old_asrmap_caches_are_removed_from_a_shared_cache_directory(tmp_path):
    import os
    import time

    keep = tmp_path / "asrmap-0123456789abcdef"
    old = tmp_path / "asrmap-fedcba9876543210"
    recent = tmp_path / "asrmap-00000000000000aa"
    foreign = tmp_path / "someone-elses-cache"
    for d in (keep, old, recent, foreign):
        d.mkdir()
        (d / "f").write_text("x")
    week_ago = time.time() - 8 * 86400
    for d in (keep, old, foreign):
        os.utime(d, (week_ago, week_ago))
    assert prune_caches(keep) == [old]
    assert keep.is_dir() and recent.is_dir() and foreign.is_dir() and not old.exists()


def test_the_warm_up_compiles_every_kernel_a_real_log_needs(shared_data):
    # A kernel first called (or called with other array types) in a real run compiles there: about
    # a second in the live service's first scans, on a machine without the cache. Replayed after
    # the warm-up, Intel raw asks no kernel for a version the warm-up did not make.
    import importlib
    import pkgutil

    from numba.core.registry import CPUDispatcher

    from mapper.warmup import warm_up
    from service.replay import replay

    modules = [importlib.import_module(f"mapper.{m.name}") for m in pkgutil.iter_modules(mapper.__path__)]
    kernels = {f"{m.__name__}.{k}": v for m in modules for k, v in vars(m).items()
               if isinstance(v, CPUDispatcher)}
    assert len(kernels) > 20
    warm_up()
    before = {k: set(v.signatures) for k, v in kernels.items()}
    replay(shared_data / "intel-raw-first5505.clf.gz")
    late = {k: new for k, v in kernels.items() if (new := set(v.signatures) - before[k])}
    assert late == {}
