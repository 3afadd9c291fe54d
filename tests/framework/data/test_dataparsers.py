"""Dataset formats are dataparsers registered in the entry-point group ``splat_framework.dataparsers``
(:mod:`splat_framework.data.dataparsers`): the built-ins, declared in the framework's pyproject.toml, in
the detection order llff, blender, dtu, transforms, colmap; a plugin's after them unless its order
says otherwise, each recognising a folder and loading it."""

from __future__ import annotations

import sys
import warnings

import pytest

from splat_framework.data import DataError, load_scene
from splat_framework.data.dataparsers import DataparserSpec, dataparsers
from splat_framework.data.parsers import detect_format
from splat_framework.entry_points import registered
from support import make_colmap, make_llff

PLUGIN = '''
from pathlib import Path

from splat_framework.plugin import DataError, DataparserSpec

ENTRY_POINTS = {"splat_framework.dataparsers": {"frames": "framer:frames", "first": "framer:first",
                                                "broken": "framer:not_a_spec", "crash": "framer:crash"}}


def crashes(folder):
    if (Path(folder) / "crash.txt").is_file():
        raise RuntimeError("the plugin's check broke")
    return False


def load(root, *, views="all", downscale=None):
    raise DataError(f"{root}: read by the plugin's frames dataparser (views={views}, downscale={downscale})")


frames = DataparserSpec("frames.txt", lambda folder: (Path(folder) / "frames.txt").is_file(), "framer:load")
first = DataparserSpec("first.txt", lambda folder: (Path(folder) / "first.txt").is_file(),
                       "framer:load", order=5)
not_a_spec = "frames"
crash = DataparserSpec("crash.txt", crashes, "framer:load")
'''


@pytest.fixture
def framer(tmp_path, monkeypatch):
    """A plugin (``SPLAT_PLUGINS=framer``) with two dataparsers (``frames``, and ``first`` tried before the
    built-ins) and an entry that is not a DataparserSpec."""
    (tmp_path / "code").mkdir()
    (tmp_path / "code" / "framer.py").write_text(PLUGIN)
    monkeypatch.syspath_prepend(str(tmp_path / "code"))
    monkeypatch.setenv("SPLAT_PLUGINS", "framer")
    dataparsers.cache_clear()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        dataparsers()
    yield [str(w.message) for w in caught]
    dataparsers.cache_clear()
    sys.modules.pop("framer", None)


def test_the_builtin_formats_register_from_the_frameworks_entry_points_in_their_detection_order():
    assert list(dataparsers())[:5] == ["llff", "blender", "dtu", "transforms", "colmap"]
    builtin = [e for e in registered("splat_framework.dataparsers") if e.source == "package splat-framework"]
    assert sorted(e.name for e in builtin) == ["blender", "colmap", "dtu", "llff", "transforms"]
    assert all(isinstance(spec, DataparserSpec) for spec in dataparsers().values())


def test_a_folder_with_transforms_json_and_a_colmap_model_is_read_as_transforms(tmp_path):
    root = make_colmap(tmp_path / "both", binary=False)
    assert detect_format(root) == "colmap"
    (root / "transforms.json").write_text("{}")
    assert detect_format(root) == "transforms"


def test_a_plugins_dataparser_recognises_and_loads_its_folders(framer, tmp_path):
    folder = tmp_path / "mine"
    folder.mkdir()
    (folder / "frames.txt").write_text("")
    names = list(dataparsers())
    assert detect_format(folder) == "frames" and names.index("frames") > names.index("colmap")  # after the built-ins
    with pytest.raises(DataError, match="read by the plugin's frames dataparser .views=3, downscale=2"):
        load_scene(folder, views=3, downscale=2)
    with pytest.raises(DataError, match="read by the plugin's frames dataparser"):
        load_scene(folder, format="frames")


def test_a_plugins_dataparser_with_a_low_order_is_tried_before_the_builtins(framer, tmp_path):
    root = make_llff(tmp_path / "l", 3)
    assert detect_format(root) == "llff"
    (root / "first.txt").write_text("")
    assert detect_format(root) == "first" and list(dataparsers())[0] == "first"


def test_an_entry_that_is_not_a_dataparser_is_left_out_with_one_line(framer):
    assert "broken" not in dataparsers()
    assert ["dataparser 'broken' of SPLAT_PLUGINS module 'framer' (framer:not_a_spec): not a DataparserSpec (str); "
            "ignored"] == [line for line in framer if "broken" in line]


def test_a_dataparser_whose_check_raises_is_one_line_naming_it(framer, tmp_path):
    (tmp_path / "c").mkdir()
    (tmp_path / "c" / "crash.txt").write_text("")
    with pytest.raises(DataError) as e:
        load_scene(tmp_path / "c")
    assert str(e.value) == (f"{tmp_path / 'c'}: dataparser 'crash' failed while recognising it "
                            "(RuntimeError: the plugin's check broke)")


def test_an_unrecognised_folder_names_every_formats_marker(framer, tmp_path):
    folder = tmp_path / "x"
    folder.mkdir()
    (folder / "notes.txt").write_text("")
    with pytest.raises(DataError) as e:
        load_scene(folder)
    message = str(e.value)
    assert "neither a dataset (first.txt, poses_bounds.npy, transforms_train.json, cameras_sphere.npz, " \
           "transforms.json, sparse/0/cameras.bin|txt" in message
    assert message.endswith("frames.txt or crash.txt) nor a folder of photos; splat-process turns your own photos or video into "
                            "a scene folder") and "\n" not in message
    with pytest.raises(DataError, match=r"unknown dataset format 'nerf' \(choose auto, first, llff, blender, dtu, "):
        load_scene(folder, format="nerf")
