"""The run's malloc thresholds (runtime/allocator.py): what is set, in which order, and when
nothing is touched."""

from __future__ import annotations

import ctypes
import os
import sys

import pytest

from splat_framework.runtime import allocator


class FakeLibc:
    def __init__(self, accept=(1, 1), glibc=True):
        self.calls = []
        self.accept = list(accept)
        if glibc:
            self.gnu_get_libc_version = lambda: b"2.36"

    def mallopt(self, param, value):
        self.calls.append((param, value))
        return self.accept[len(self.calls) - 1]


@pytest.fixture
def clean_env(monkeypatch):
    for key in [k for k in os.environ if k.startswith("MALLOC_")] + ["GLIBC_TUNABLES"]:
        monkeypatch.delenv(key, raising=False)


def test_sets_the_mmap_threshold_then_the_trim_threshold(clean_env):
    libc = FakeLibc()
    assert allocator.keep_freed_memory(libc)
    assert libc.calls == [(allocator.M_MMAP_THRESHOLD, 32 * 2**20), (allocator.M_TRIM_THRESHOLD, 2**30)]


def test_no_trim_threshold_when_the_mmap_threshold_was_refused(clean_env):
    # a trim threshold alone would freeze the mmap threshold at 128 KiB: steps twice as long
    libc = FakeLibc(accept=(0, 1))
    assert not allocator.keep_freed_memory(libc)
    assert libc.calls == [(allocator.M_MMAP_THRESHOLD, 32 * 2**20)]


def test_leaves_a_users_own_malloc_settings_and_other_c_libraries_alone(clean_env, monkeypatch):
    assert not allocator.keep_freed_memory(FakeLibc(glibc=False))  # musl, macOS: not glibc's malloc
    monkeypatch.setenv("MALLOC_ARENA_MAX", "2")
    libc = FakeLibc()
    assert not allocator.keep_freed_memory(libc)
    monkeypatch.delenv("MALLOC_ARENA_MAX")
    monkeypatch.setenv("GLIBC_TUNABLES", "glibc.malloc.mmap_threshold=65536")
    assert not allocator.keep_freed_memory(libc)
    assert libc.calls == []


@pytest.mark.skipif(not sys.platform.startswith("linux") or not hasattr(ctypes.CDLL(None), "gnu_get_libc_version"),
                    reason="glibc only")
def test_glibc_accepts_the_thresholds(clean_env):
    assert allocator.keep_freed_memory()


def test_a_training_run_applies_them(tmp_path, monkeypatch):
    from test_trainer import tiny_config

    import splat_framework.engine.trainer as trainer_mod
    import splat_framework.runtime.process as process

    calls = []
    monkeypatch.setattr(process, "keep_freed_memory", lambda: calls.append(1) or True)
    trainer_mod.Trainer(tiny_config(tmp_path / "run", steps=2, progress=False))
    assert calls == [1]
