"""Nothing runs from a file the user did not write (issue 60): a cache folder others may write is
refused, and a native library or a saved compiled graph planted in the cache (each of which would
touch a marker file when loaded) is never loaded; what the project itself built is."""

from __future__ import annotations

import os
import pickle
import shutil
import subprocess
import sys
import warnings
from pathlib import Path

import pytest
import torch

from splat_framework.runtime.trusted import (
    MANIFEST,
    folder_mismatch,
    manifest_mismatch,
    private_folder,
    untrusted_reason,
    write_folder_manifest,
    write_manifest,
)

needs_owners = pytest.mark.skipif(not hasattr(os, "geteuid"), reason="file owners and modes are POSIX")


@needs_owners
def test_a_folder_or_file_others_may_write_is_not_trusted(tmp_path):
    folder = private_folder(tmp_path / "cache" / "native")
    assert (folder.stat().st_mode & 0o777) == 0o700 and untrusted_reason(folder, tmp_path / "cache") is None
    (folder / "lib.so").write_bytes(b"x")
    os.chmod(folder / "lib.so", 0o666)
    assert untrusted_reason(folder / "lib.so", tmp_path / "cache") == f"{folder / 'lib.so'}: writable by others (mode 666)"
    os.chmod(folder / "lib.so", 0o600)
    os.chmod(folder, 0o770)
    assert untrusted_reason(folder / "lib.so", tmp_path / "cache") == f"{folder}: writable by its group (mode 770)"


def test_a_manifest_vouches_for_exactly_the_bytes_it_recorded(tmp_path):
    folder = private_folder(tmp_path / "f")
    (folder / "a.bin").write_bytes(b"one")
    assert "missing, unreadable or not signed" in manifest_mismatch(folder, ["a.bin"])
    write_manifest(folder, ["a.bin"])
    assert manifest_mismatch(folder, ["a.bin"]) is None
    (folder / "a.bin").write_bytes(b"two")
    assert manifest_mismatch(folder, ["a.bin"]) == (
        f"{folder / 'a.bin'}: its content differs from the one recorded in {MANIFEST} when it was built")
    (folder / "b.bin").write_bytes(b"new")
    assert manifest_mismatch(folder, ["b.bin"]) == f"{folder / 'b.bin'}: not in {MANIFEST}"
    (folder / MANIFEST).write_text((folder / MANIFEST).read_text().replace("a.bin", "b.bin"))  # edited by hand
    assert "missing, unreadable or not signed" in manifest_mismatch(folder, ["b.bin"])


def test_a_folder_manifest_sees_added_removed_and_linked_files(tmp_path):
    folder = private_folder(tmp_path / "entry")
    (folder / "sub").mkdir()
    (folder / "sub" / "x.txt").write_text("x")
    write_folder_manifest(folder)
    assert folder_mismatch(folder) is None
    (folder / "sub" / "y.txt").write_text("y")
    assert folder_mismatch(folder) == f"{folder / 'sub' / 'y.txt'}: not in {MANIFEST}"
    (folder / "sub" / "y.txt").unlink()
    (folder / "sub" / "x.txt").rename(folder / "sub" / "z.txt")
    assert folder_mismatch(folder) == f"{folder / 'sub' / 'x.txt'}: missing"
    (folder / "sub" / "z.txt").rename(folder / "sub" / "x.txt")
    (folder / "link").symlink_to(tmp_path)
    assert folder_mismatch(folder) == f"{folder / 'link'}: a symbolic link"


@needs_owners
@pytest.mark.bad_input("`$SPLAT_CACHE` (or `~/.cache/splat`) belonging to another user or writable by others",
                       "one warning line naming the folder and why; a private folder under the temporary folder is used")
def test_a_cache_folder_others_may_write_is_refused_in_one_line_and_another_used(tmp_path, monkeypatch):
    from splat_framework.data import cache_dir

    shared = tmp_path / "shared-cache"
    shared.mkdir()
    os.chmod(shared, 0o777)
    monkeypatch.setenv("SPLAT_CACHE", str(shared))
    monkeypatch.setattr(cache_dir, "_REFUSED", {})
    with pytest.warns(UserWarning) as caught:
        used = cache_dir.user_cache_dir()
    (message,) = [str(w.message) for w in caught]
    assert message == f"cache folder refused: {shared}: writable by others (mode 777); using {used} instead"
    assert used != shared and untrusted_reason(used) is None
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert cache_dir.user_cache_dir() == used  # warned once per process
    os.chmod(shared, 0o700)
    monkeypatch.setattr(cache_dir, "_REFUSED", {})
    assert cache_dir.user_cache_dir() == shared


def _planted_library(path: Path, marker: Path) -> None:
    """A shared library whose constructor creates ``marker`` when anything loads it."""
    cc = shutil.which("cc") or shutil.which("gcc")
    if cc is None:
        pytest.skip("needs a C compiler to build the planted library")
    src = path.with_suffix(".c")
    src.write_text('#include <stdio.h>\n__attribute__((constructor)) static void planted(void) '
                   f'{{ FILE *f = fopen("{marker}", "w"); if (f) fclose(f); }}\n')
    subprocess.run([cc, "-shared", "-fPIC", "-o", str(path), str(src)], check=True)
    src.unlink()


def _planted_native_build(tmp_path, monkeypatch, regenerated: bool = False):
    """(cache, build folder, marker, the builds done): a library planted in the native cache's build
    folder (touching ``marker`` when loaded), its manifest regenerated under another key when
    ``regenerated``, and torch's builder replaced by one that loads every library it finds (as torch
    does) and, finding none, leaves what the real builder leaves."""
    import ctypes

    from torch.utils import cpp_extension

    from splat_framework.render import _native

    cache, marker = private_folder(tmp_path / "cache"), tmp_path / "marker"
    build = _native._build_dir(cache)
    private_folder(build)
    _planted_library(build / "splat_native.so", marker)
    if regenerated:
        _regenerated_elsewhere(build, ["splat_native.so"], monkeypatch, tmp_path)
    built = []

    def fake_load(name, sources, build_directory, **kwargs):  # torch loads every library it finds there
        libraries = sorted(Path(build_directory).glob("*.so"))
        for lib in libraries:
            ctypes.CDLL(str(lib))
        if not libraries:  # a build: what the real builder leaves
            (Path(build_directory) / "splat_native.so").write_bytes(b"built here")
            built.append(build_directory)
        return "module"

    monkeypatch.setattr(cpp_extension, "load", fake_load)
    monkeypatch.setattr(_native, "_STATE", {"module": None, "failed": False})
    return cache, build, marker, built


@needs_owners
@pytest.mark.bad_input("a native kernels library in the cache that the project did not build (planted, swapped or edited)",
                       "never loaded: one warning line naming the file, the kernels built again")
def test_a_planted_native_library_is_never_loaded_and_the_kernels_are_built_again(tmp_path, monkeypatch):
    from torch.utils import cpp_extension

    from splat_framework.render import _native

    cache, build, marker, built = _planted_native_build(tmp_path, monkeypatch)
    fake_load = cpp_extension.load  # the helper's builder, put back below
    with pytest.warns(UserWarning) as caught:
        assert _native.native_kernels(cache) == "module"
    assert not marker.exists()
    (message,) = [str(w.message) for w in caught]
    assert message.startswith(f"native rasterizer kernels not loaded: {build / MANIFEST}: missing") and message.endswith(
        "building them again")
    assert built == [str(build)] and manifest_mismatch(build, ["splat_native.so"], cache) is None

    # what was built here is loaded without a word (imported as it is: no build tool asked); the
    # same library swapped afterwards is not
    monkeypatch.setattr(_native, "_STATE", {"module": None, "failed": False})
    monkeypatch.setattr(cpp_extension, "load", lambda **kw: pytest.fail("a checked library is not built again"))
    monkeypatch.setattr(_native, "_import_library", lambda library: f"loaded {library.name}")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert _native.native_kernels(cache) == "loaded splat_native.so"
    _planted_library(build / "splat_native.so", marker)
    monkeypatch.setattr(_native, "_STATE", {"module": None, "failed": False})
    monkeypatch.setattr(cpp_extension, "load", fake_load)
    with pytest.warns(UserWarning, match="its content differs from the one recorded"):
        _native.native_kernels(cache)
    assert not marker.exists()


class _Planted:
    """Unpickling this creates the marker file (what a hostile pickle would do instead)."""

    def __init__(self, marker: str):
        self.marker = marker

    def __reduce__(self):
        return (open, (self.marker, "w"))


class _FakeGraph:
    def __init__(self, tag: str):
        self.tag = tag

    def guard_check(self, *args):
        return True

    def __call__(self, *args):
        return self.tag

    def save_compiled_function(self, path: str) -> None:
        Path(path).write_bytes(pickle.dumps(self.tag))


def _planted_graph(tmp_path, monkeypatch, regenerated: bool = False):
    """(kernel, its args, marker, folder, file stem, the compiles done): a pickle planted as the
    kernel's saved graph (touching ``marker`` when unpickled), its manifest regenerated under another
    key when ``regenerated``; compiling and loading faked."""
    from splat_framework.render.precompiled import Precompiled

    marker, folder = tmp_path / "marker", tmp_path / "cache" / "precompiled"
    kernel = Precompiled("fwd", lambda x: x, lambda args: (), folder, fallback=lambda *a: "fallback")
    args = (torch.zeros(2),)
    stem = kernel.stem_for(args)
    private_folder(folder)
    (folder / f"{stem}-0.bin").write_bytes(pickle.dumps(_Planted(str(marker))))
    if regenerated:
        _regenerated_elsewhere(folder, [f"{stem}-0.bin"], monkeypatch, tmp_path)
    compiled = []
    monkeypatch.setattr(kernel, "_compile", lambda a: compiled.append(1) or _FakeGraph("compiled here"))
    monkeypatch.setattr(torch.compiler, "load_compiled_function", lambda f: _FakeGraph(pickle.load(f)), raising=False)
    return kernel, args, marker, folder, stem, compiled


@pytest.mark.bad_input("a saved compiled graph in the cache that the project did not save, or one that fails to load",
                       "never unpickled: one warning line naming the file, compiled again")
def test_a_planted_compiled_graph_is_never_unpickled_and_a_saved_one_is_loaded(tmp_path, monkeypatch):
    kernel, args, marker, folder, stem, compiled = _planted_graph(tmp_path, monkeypatch)
    with pytest.warns(UserWarning) as caught:
        graph = kernel._load_or_compile(args)
    assert not marker.exists() and graph() == "compiled here" and compiled == [1]
    (message,) = [str(w.message) for w in caught]
    assert message.startswith(f"compiled rasterizer kernels not loaded: {folder / MANIFEST}: missing")
    assert sorted(p.name for p in folder.glob("*.bin")) == [f"{stem}-0.bin"]  # the planted file is gone
    # the graph saved just now loads, without a word
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert kernel._load_or_compile(args)() == "compiled here" and compiled == [1]
    # a load that fails is reported, not swallowed
    monkeypatch.setattr(torch.compiler, "load_compiled_function", lambda f: 1 / 0, raising=False)
    with pytest.warns(UserWarning) as caught:
        kernel._load_or_compile(args)
    assert [str(w.message) for w in caught][0] == (
        f"{folder / (stem + '-0.bin')}: compiled rasterizer kernels not loaded (ZeroDivisionError: division by zero); "
        "compiling them again")


def test_the_planted_pickle_would_have_run_without_the_check(tmp_path):
    """The test above's pickle is a real threat: unpickled, it creates its marker."""
    marker = tmp_path / "marker"
    pickle.loads(pickle.dumps(_Planted(str(marker))))
    assert marker.exists()


if sys.platform == "win32":  # pragma: no cover
    pytestmark = pytest.mark.skip(reason="POSIX file modes")


def test_on_macos_the_native_kernels_are_built_without_openmp(monkeypatch):
    """Issue 62: Apple's clang takes no -fopenmp; the kernels then build without it (at::parallel_for
    runs them on one thread) into a build folder of their own."""
    from splat_framework.render import _native

    monkeypatch.setattr(sys, "platform", "linux")
    linux, linux_dir = _native._flags(), _native._build_dir(Path("/c"))
    assert "-fopenmp" in linux and _native._openmp()
    monkeypatch.setattr(sys, "platform", "darwin")
    mac = _native._flags()
    assert "-fopenmp" not in mac and "-march=native" not in mac and not _native._openmp()
    assert _native._build_dir(Path("/c")) != linux_dir  # a cache shared with a Linux build never mixes them


def test_without_os_uname_the_native_build_folder_is_still_named(monkeypatch):
    """Windows has no os.uname: naming the build folder and its flags must not need it (the build
    then fails or falls back like any other, instead of crashing before it)."""
    from splat_framework.render import _native

    monkeypatch.delattr(os, "uname")
    assert _native._flags() and _native._build_dir(Path("/c")).name.startswith("kernels-")


def _regenerated_elsewhere(folder: Path, names: list[str], monkeypatch, tmp_path: Path) -> None:
    """A manifest for ``names`` regenerated as anyone could from the public source: by the same code,
    signed with another user's key (another config folder), then the user's own key back."""
    monkeypatch.setenv("XDG_CONFIG_HOME", str(tmp_path / "someone-else"))
    write_manifest(folder, names)
    monkeypatch.setenv("XDG_CONFIG_HOME", str(tmp_path / "me"))


@needs_owners
def test_a_manifest_signed_with_another_key_or_a_linked_file_vouches_for_nothing(tmp_path, monkeypatch):
    monkeypatch.setenv("XDG_CONFIG_HOME", str(tmp_path / "me"))
    folder = private_folder(tmp_path / "cache")
    (folder / "a.bin").write_bytes(b"x")
    _regenerated_elsewhere(folder, ["a.bin"], monkeypatch, tmp_path)
    assert "not signed by this user's key" in manifest_mismatch(folder, ["a.bin"])
    write_manifest(folder, ["a.bin"])  # the user's own
    assert manifest_mismatch(folder, ["a.bin"]) is None
    key = tmp_path / "me" / "splat" / "cache-key"
    assert (key.stat().st_mode & 0o777) == 0o600 and (key.parent.stat().st_mode & 0o777) == 0o700
    shared = tmp_path / "shared"
    shared.mkdir()
    os.chmod(shared, 0o777)
    (shared / "a.bin").write_bytes(b"x")  # identical bytes, in a folder anyone may write
    (folder / "a.bin").unlink()
    (folder / "a.bin").symlink_to(shared / "a.bin")
    assert manifest_mismatch(folder, ["a.bin"]) == f"{folder / 'a.bin'}: a symbolic link"


@needs_owners
@pytest.mark.bad_input("a planted native library or compiled graph with a manifest regenerated for it (another key), or "
                       "a link to an identical file", "never loaded: one warning line naming the file, built again")
def test_a_planted_library_with_a_regenerated_manifest_is_never_loaded(tmp_path, monkeypatch):
    from splat_framework.render import _native

    monkeypatch.setenv("XDG_CONFIG_HOME", str(tmp_path / "me"))
    cache, build, marker, built = _planted_native_build(tmp_path, monkeypatch, regenerated=True)
    with pytest.warns(UserWarning) as caught:
        assert _native.native_kernels(cache) == "module"
    assert not marker.exists() and built == [str(build)]
    (message,) = [str(w.message) for w in caught]
    assert message.startswith(f"native rasterizer kernels not loaded: {build / MANIFEST}: missing, unreadable or not "
                              "signed by this user's key") and "could not" not in message


@needs_owners
def test_a_planted_graph_with_a_regenerated_manifest_is_never_unpickled(tmp_path, monkeypatch):
    monkeypatch.setenv("XDG_CONFIG_HOME", str(tmp_path / "me"))
    kernel, args, marker, folder, stem, compiled = _planted_graph(tmp_path, monkeypatch, regenerated=True)
    with pytest.warns(UserWarning) as caught:
        graph = kernel._load_or_compile(args)
    assert not marker.exists() and graph() == "compiled here" and compiled == [1]
    (message,) = [str(w.message) for w in caught]
    assert message.startswith(f"compiled rasterizer kernels not loaded: {folder / MANIFEST}: missing, unreadable or not signed")


def _unusable_key(config: Path, case: str) -> Path:
    """``config/splat/cache-key`` made unusable as ``case`` says; the key file."""
    key = config / "splat" / "cache-key"
    private_folder(key.parent)
    good = "ab" * 32
    if case == "mode 644":
        key.write_text(good)
        os.chmod(key, 0o644)
    elif case == "folder":
        key.mkdir()
    elif case == "symlink":
        (key.parent / "elsewhere").write_text(good)
        os.chmod(key.parent / "elsewhere", 0o600)
        key.symlink_to(key.parent / "elsewhere")
    elif case == "not hex":
        key.write_text("not a key at all")
        os.chmod(key, 0o600)
    elif case == "fifo":
        os.mkfifo(key, 0o600)  # opening it for reading would block forever
    elif case == "folder 777":
        key.write_text(good)
        os.chmod(key, 0o600)
        os.chmod(key.parent, 0o777)
    return key


UNUSABLE_KEYS = {"mode 644": ("mode 644", "rm -r"), "folder": ("a folder, not a file", "rm -r"),
                 "symlink": ("a symbolic link, not a file", "rm -r"), "not hex": ("does not hold a key", "rm -r"),
                 "fifo": ("a FIFO, not a file", "rm -r"), "folder 777": ("writable by others (mode 777)", "chmod 700")}
SIGN_AND_CHECK = """
import sys
from splat_framework.runtime.trusted import manifest_mismatch, write_manifest
if sys.argv[2] == "write":
    write_manifest(sys.argv[1], ["a.bin"])
print(manifest_mismatch(sys.argv[1], ["a.bin"]))
"""


@needs_owners
@pytest.mark.parametrize("case", sorted(UNUSABLE_KEYS))
@pytest.mark.bad_input("an unusable cache signing key (mode 0644, a folder, a symlink, not hex, a FIFO, a 0777 config "
                       "folder)", "one warning line a process naming the key file, what is wrong and the command that "
                       "fixes it; a FIFO is never opened; the caches' check names the key, not the manifest")
def test_an_unusable_signing_key_is_one_warning_naming_it_and_the_fix(tmp_path, case):
    """The process signs with a key of its own (its own caches verify), warns once naming the key file, what
    is wrong and the fixing command; the next process's check of those caches names the key as the cause.
    A FIFO is never opened (the command would hang)."""
    key = _unusable_key(tmp_path / "config", case)
    folder = private_folder(tmp_path / "cache")
    (folder / "a.bin").write_bytes(b"x")
    env = {**os.environ, "XDG_CONFIG_HOME": str(tmp_path / "config")}
    what, fix = UNUSABLE_KEYS[case]
    for step, verdict in (("write", "None"), ("check", "not signed by this process's key")):
        r = subprocess.run([sys.executable, "-W", "default", "-c", SIGN_AND_CHECK, str(folder), step], env=env,
                           capture_output=True, text=True, timeout=60)
        lines = [line for line in r.stderr.splitlines() if "Warning: " in line]
        assert r.returncode == 0 and len(lines) == 1, r.stderr
        assert f"{key}: unusable cache signing key: " in lines[0] and what in lines[0] and fix in lines[0], lines
        assert verdict in r.stdout and (step == "write" or f"signing key {key}: " in r.stdout), r.stdout
