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
