"""The fast tier covers the whole product: every package of ``src/`` has at least one fast test that
uses it (``tests/tiers.py`` records which, as it marks the slow ones)."""

from __future__ import annotations

import pytest

from tiers import TESTS, package_coverage, src_packages


def test_every_src_package_has_a_fast_test(request):
    covered, files = package_coverage(request.config)
    unread = sorted(str(p.relative_to(TESTS)) for p in TESTS.rglob("test_*.py") if str(p) not in files)
    if unread:
        pytest.skip(f"this run collected a part of the suite ({len(unread)} test files left out, e.g. {unread[0]})")
    assert set(covered) == src_packages()
    missing = sorted(package for package, tests in covered.items() if not tests)
    assert not missing, f"no fast test uses {', '.join(missing)}: add one, or see why its tests are slow (--why-slow)"


def test_a_seeded_cache_holds_the_machines_kernels_as_the_product_loads_them(tmp_path, _native_kernels_loaded):
    """A test's own cache gets the machine's built kernels (the library and its signed manifest) in
    the folder the product looks in, and passes the product's checks, so a command on it loads them;
    a build under a folder after a moment is found, one from before it is not."""
    import os
    import time

    from splat_framework.render import _native
    from splat_framework.runtime.trusted import manifest_mismatch
    from tiers import KERNELS, kernels_built_under, seed_kernels

    if not _native_kernels_loaded:
        pytest.skip("the native kernels could not be built on this machine: nothing to seed")
    cache = seed_kernels(tmp_path / "cache")
    target = _native._build_dir(cache)
    assert target.name == KERNELS["folder"].name and (target / "splat_native.so").is_file()
    assert manifest_mismatch(target, ["splat_native.so"], cache) is None
    assert seed_kernels(cache) == cache  # a second seed keeps what is there
    assert kernels_built_under(tmp_path, time.time() - 60) == []  # a seed is not a build
    old = tmp_path / "a" / "native" / "kernels-1" / "build.ninja"
    new = tmp_path / "b" / "native" / "kernels-2" / "build.ninja"
    for f in (old, new):
        f.parent.mkdir(parents=True)
        f.write_text("")
    os.utime(old, (time.time() - 3600,) * 2)
    assert kernels_built_under(tmp_path, time.time() - 60) == [new.parent]
    new.unlink()  # not a build for the session's summary to name
