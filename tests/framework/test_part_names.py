"""The one rule of every kind of registered part (methods, variants, strategies, inits, photo matchers, dataparsers):
names are names, a taken name keeps its first registration (the framework's own first), and a
variant shapes the experiment, never the run (``splat_framework.entry_points.Parts``,
``splat_framework.registry``)."""

import os
import shutil
import sys
import warnings

import pytest

from cli_harness import cli_env, run_cli
from splat_framework import registry
from splat_framework.config import TrainConfig
from splat_framework.config.base import RUN_OPTION

PLUGIN = '''
from typing import Literal

from splat_framework.plugin import DataparserSpec, InitConfig, Kind, MethodSpec, StrategyConfig, TrainConfig

ENTRY_POINTS = {
    "splat_framework.methods": {"3dgs": "taker:spec"},
    "splat_framework.strategies": {"default": "taker:TakerStrategy"},
    "splat_framework.inits": {"random": "taker:TakerInit"},
    "splat_framework.photo_matchers": {"aliked-lightglue": "taker:match"},
    "splat_framework.configs": {"taker": "taker_configs"},
    "splat_framework.dataparsers": {"llff": "taker:parser"},
}


def config():
    return TrainConfig(method="3dgs", default_steps=7)


spec = MethodSpec(name="3dgs", description="not the framework's 3dgs", config_factory=config,
                  model="splat_framework.model.gaussians:GaussianModel")


class TakerStrategy(StrategyConfig):
    kind: Kind[Literal["default"]] = "default"
    strategy_class = "taker:Nothing"


class TakerInit(InitConfig):
    kind: Kind[Literal["random"]] = "random"
    points_fn = "taker:nothing"


def match(images, pairs=None):
    raise SystemExit("the plugin's matcher ran")


parser = DataparserSpec("poses_bounds.npy", lambda folder: True, "taker:nothing")
'''


@pytest.fixture
def taker(tmp_path, monkeypatch):
    """A plugin (``SPLAT_PLUGINS=taker``) declaring a part of every kind under a built-in's name; its
    environment for a CLI run."""
    code = tmp_path / "code"
    (code / "taker_configs").mkdir(parents=True)
    (code / "taker.py").write_text(PLUGIN)
    (code / "taker_configs" / "__init__.py").write_text("")
    (code / "taker_configs" / "3dgs-frustum.toml").write_text('base = "3dgs"\ndescription = "the plugin\'s"\n'
                                                             '[overrides]\nsteps = 5\n')
    monkeypatch.syspath_prepend(str(code))
    monkeypatch.setenv("SPLAT_PLUGINS", "taker")
    path = os.pathsep.join(p for p in (str(code), os.environ.get("PYTHONPATH")) if p)
    yield cli_env(PYTHONPATH=path, SPLAT_PLUGINS="taker")
    for module in ("taker", "taker_configs"):  # another test's tmp_path holds its own
        sys.modules.pop(module, None)


def _builtin_strategy():
    from splat_framework.config import DensifyConfig, strategy_kinds

    strategy_kinds.cache_clear()
    return strategy_kinds()["default"] is DensifyConfig


def _builtin_init():
    from splat_framework.config import RandomInitConfig, init_kinds

    init_kinds.cache_clear()
    return init_kinds()["random"] is RandomInitConfig


def _builtin_photo_matcher():
    from splat_framework.sfm.photo_matchers import photo_matchers

    return photo_matchers()["aliked-lightglue"].value == "splat_framework.matching.photos:aliked_lightglue"


def _builtin_dataparser():
    from splat_framework.data.dataparsers import dataparsers, llff

    dataparsers.cache_clear()
    try:
        return dataparsers()["llff"] is llff
    finally:
        dataparsers.cache_clear()  # the plugin's module leaves with the test


KINDS = {
    "method": (lambda: registry.discover_methods()["3dgs"].description != "not the framework's 3dgs",
               "method '3dgs' of SPLAT_PLUGINS module 'taker' (taker:spec) is already registered by package "
               "splat-framework (splat_framework.methods.gaussian_splatting:spec_3dgs)"),
    "variant": (lambda: registry.discover_methods()["3dgs-frustum"].description != "the plugin's",
                "config variant '3dgs-frustum' of {code}/taker_configs/3dgs-frustum.toml is already registered by "
                "{repo}/configs/3dgs-frustum.toml"),
    "strategy": (_builtin_strategy, "strategy 'default' of SPLAT_PLUGINS module 'taker' (taker:TakerStrategy) is "
                 "already registered by the framework (splat_framework.config.strategy:DensifyConfig)"),
    "init": (_builtin_init, "initialisation 'random' of SPLAT_PLUGINS module 'taker' (taker:TakerInit) is already "
             "registered by the framework (splat_framework.config.init:RandomInitConfig)"),
    "photo matcher": (_builtin_photo_matcher, "photo matcher 'aliked-lightglue' of SPLAT_PLUGINS module 'taker' "
                      "(taker:match) is already registered by package splat-framework "
                      "(splat_framework.matching.photos:aliked_lightglue)"),
    "dataparser": (_builtin_dataparser, "dataparser 'llff' of SPLAT_PLUGINS module 'taker' (taker:parser) is already "
                   "registered by package splat-framework (splat_framework.data.dataparsers:llff)"),
}


@pytest.mark.parametrize("kind", sorted(KINDS))
@pytest.mark.bad_input("a plugin's method, variant, strategy, init, photo matcher or dataparser named like a built-in one",
                       "one warning line naming both sources; the built-in keeps the name")
def test_a_plugins_part_named_like_a_builtin_leaves_the_builtin_in_place(taker, tmp_path, kind):
    """For every kind of part, a plugin's entry under a built-in's name is left out with one warning naming
    both sources, and the name keeps its meaning."""
    from support import REPO

    builtin_kept, expected = KINDS[kind]
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        assert builtin_kept()
    lines = [str(w.message) for w in caught if "already registered" in str(w.message)]
    expected = expected.format(code=tmp_path / "code", repo=REPO)
    assert f"{expected}, which keeps it; ignored" in lines, lines
    assert all("\n" not in line for line in lines)


@pytest.mark.bad_input("a plugin's photo matcher named like a built-in one (`aliked-lightglue`)",
                       "one warning line naming both; the built-in keeps the name and `--matcher auto` picks it")
def test_a_plugins_photo_matcher_named_like_the_builtin_is_one_warning_line(taker, tmp_path):
    """Through the commands: ``--matcher`` lists the framework's matchers once, with one warning naming
    the plugin's entry and the built-in."""
    from support import write_png

    photos = tmp_path / "photos"
    for i in range(2):
        write_png(photos / f"p{i}.png", 32, 24, seed=i)
    r = run_cli("process", "images", photos, "--out", tmp_path / "scene", "--matcher", "nosuch", code=2,
                env=taker, max_lines=None, watch=[tmp_path])
    warned = [line for line in r.message.splitlines() if line.startswith("warning: photo matcher")]
    assert len(warned) == 1 and "SPLAT_PLUGINS module 'taker'" in warned[0] and "splat-framework" in warned[0], r.stderr


@pytest.mark.bad_input("a user's variant file named like a method (`3dgs.toml` on scgaussian) or a shipped variant",
                       "one warning line naming both; the method and the variants built on it keep their meaning")
def test_a_users_variant_named_like_a_method_changes_nothing(tmp_path):
    """A user's ``3dgs.toml`` (on scgaussian) is refused with one line naming both; ``3dgs`` and the shipped
    variants built on it keep their meaning (``3dgs-triang`` is not reported invalid)."""
    user = tmp_path / "user"
    user.mkdir()
    (user / "3dgs.toml").write_text('base = "scgaussian"\n')
    env = cli_env(SPLAT_CONFIG_PATH=user)
    r = run_cli("train", "--help", code=0, env=env)
    lines = [line for line in r.stderr.splitlines() if line.strip()]
    assert lines == [f"warning: config variant '3dgs' of {user / '3dgs.toml'} is already registered by package "
                     "splat-framework (splat_framework.methods.gaussian_splatting:spec_3dgs), which keeps it; ignored"]
    assert "3dgs-triang" in r.stdout
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        methods = registry.discover_methods(config_dirs=[user, *registry.default_config_dirs()])
    from splat_framework.methods.gaussian_splatting import spec_3dgs

    kept = methods["3dgs"]  # the framework's spec, with who declared it filled in
    assert kept.config_factory is spec_3dgs.config_factory and kept.source.startswith("package splat-framework")
    assert methods["3dgs-frustum"].model == spec_3dgs.model
    assert methods["3dgs-frustum"].default_config().strategy.kind == "default"


BAD_NAMES = {"a b": "space", "3dgs\u200b": "zero-width space", "x\ny": "newline", "Big": "capital", "-x": "leading hyphen"}


@pytest.mark.bad_input("a variant file or plugin entry whose name is not a name (`a b.toml`, `3dgs\\u200b`, a newline, "
                       "capitals)", "one warning line naming the file; asking for it: exit 2, one line; `--help` intact")
def test_names_that_are_not_names_are_refused_naming_the_file(tmp_path):
    for name in BAD_NAMES:
        (tmp_path / f"{name}.toml").write_text('base = "3dgs"\n')
    env = cli_env(SPLAT_CONFIG_PATH=tmp_path)
    r = run_cli("train", "--help", code=0, env=env)
    warned = [line for line in r.stderr.splitlines() if line.strip()]
    assert len(warned) == len(BAD_NAMES) and all("is not a name" in line for line in warned), r.stderr
    assert "3dgs\u200b" not in r.stdout and "a b" not in r.stdout
    run_cli("train", "a b", "--data", "synthetic/forward-tiny", code=2, env=env, watch=[tmp_path],
            match=(str(tmp_path / "a b.toml"), "'a b' is not a name"))


def _variant(folder, name: str, text: str):
    folder.mkdir(parents=True, exist_ok=True)
    (folder / f"{name}.toml").write_text(text)
    return cli_env(SPLAT_CONFIG_PATH=folder)


@pytest.mark.bad_input("a TOML variant setting a run option (`output` and `overwrite = true` naming a finished run, "
                       "`viewer_host = \"0.0.0.0\"`), on `$SPLAT_CONFIG_PATH` or in a plugin's package",
                       "exit 2 when asked for, one line naming the file and the option; the run is untouched")
def test_a_variant_setting_a_run_option_is_refused_and_the_run_it_names_is_untouched(run_dir, tmp_path):
    """``[overrides] output = "<a finished run>"``, ``overwrite = true``: refused naming the file and the key;
    the victim run's files are byte-identical. The viewer's address is refused the same way."""
    victim = tmp_path / "victim"
    shutil.copytree(run_dir, victim)
    env = _variant(tmp_path / "variants", "evil", f'base = "3dgs"\n[overrides]\noutput = "{victim}"\n'
                                                   'overwrite = true\nsteps = 3\n')
    run_cli("train", "evil", "--data", "synthetic/forward-tiny", "--no-progress", code=2, env=env,
            match=(str(tmp_path / "variants" / "evil.toml"), "overrides.output is a run option", "--output"),
            watch=[victim])
    env = _variant(tmp_path / "viewer", "open", 'base = "3dgs"\n[overrides]\nviewer = true\nviewer_host = "0.0.0.0"\n')
    run_cli("train", "open", "--data", "synthetic/forward-tiny", code=2, env=env, watch=[tmp_path],
            match=("open.toml", "overrides.viewer is a run option"))


def test_every_run_option_is_refused_in_a_variant_and_comes_from_the_command_line_with_load_config(tmp_path):
    """Walking TrainConfig's fields: every field marked RUN_OPTION (and no other) is refused in a variant,
    and ``--load-config`` takes each from the method's defaults, not from the file: one list for both."""
    from splat_framework.cli.train import load_saved_experiment
    from splat_framework.config import run_options, save_config

    marked = {n for n, f in TrainConfig.model_fields.items() if any(m is RUN_OPTION for m in f.metadata)}
    assert run_options(TrainConfig) == marked and {"output", "overwrite", "resume", "viewer_host", "device"} <= marked
    for name in TrainConfig.model_fields:
        (tmp_path / f"v-{name.replace('_', '-')}.toml").write_text(f'base = "3dgs"\n[overrides]\n{name} = "x"\n')
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        registry.discover_methods(config_dirs=[tmp_path])
    refused = {n for n in TrainConfig.model_fields
               if "is a run option" in (registry.left_out(f"v-{n.replace('_', '-')}") or "")}
    assert refused == marked, caught
    changed = {"output": tmp_path / "old-run", "overwrite": True, "resume": True, "viewer": True,
               "viewer_host": "0.0.0.0", "viewer_port": 9999, "viewer_every": 7, "device": "cuda:3",
               "eval_every": 11, "progress": False, "save_renders": False, "compile": False, "rasterizer": "torch",
               "trust_edited_config": True, "resolved_data": None}
    assert set(changed) == marked, "a new run option: give it a changed value here"
    spec = registry.get_method("3dgs")
    saved = spec.default_config().model_copy(update={**changed, "seed": 5})
    save_config(saved, tmp_path / "config.json")
    method, loaded = load_saved_experiment(str(tmp_path / "config.json"), {"3dgs": spec})
    defaults = spec.default_config()
    assert method == "3dgs" and loaded.seed == 5
    assert {n: getattr(loaded, n) for n in marked} == {n: getattr(defaults, n) for n in marked}


@pytest.mark.bad_input("a TOML variant with an unknown top-level key or table (`descripton`, `stepz`, "
                       "`[override.model]`), or whose base is itself left out",
                       "one warning line naming the file and the key (with a did-you-mean); exit 2 when asked for")
def test_unknown_keys_and_tables_of_a_variant_are_refused_by_name(tmp_path):
    cases = {
        "typo-table": ('base = "3dgs"\n[override.model]\nsh_degree = 1\n', "unknown key 'override' (did you mean 'overrides'?)"),
        "typo-key": ('base = "3dgs"\ndescripton = "x"\n', "unknown key 'descripton' (did you mean 'description'?)"),
        "stray": ('base = "3dgs"\nstepz = 5\n', "unknown key 'stepz'"),
        "on-broken": ('base = "typo-key"\n', "base 'typo-key' is left out ("),
    }
    for name, (text, _) in cases.items():
        (tmp_path / f"{name}.toml").write_text(text)
    env = cli_env(SPLAT_CONFIG_PATH=tmp_path)
    for name, (_, why) in cases.items():
        run_cli("train", name, "--data", "synthetic/forward-tiny", code=2, env=env, watch=[tmp_path],
                match=(str(tmp_path / f"{name}.toml"), why))


def test_an_installed_plugin_that_exits_or_fails_on_import_is_one_warning_and_asking_for_it_one_line(tmp_path,
                                                                                                   monkeypatch):
    """An installed entry point whose module calls ``sys.exit(0)`` or raises ``KeyboardInterrupt`` while
    importing is left out with one warning naming it and what it raised (the command goes on); asking
    for the method it declared is one DataError line saying why."""
    from importlib.metadata import EntryPoint

    from splat_framework import entry_points as plugins
    from splat_framework.errors import DataError

    (tmp_path / "exits_on_import.py").write_text("import sys\nsys.exit(0)\n")
    (tmp_path / "interrupts_on_import.py").write_text("raise KeyboardInterrupt\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    group = registry.ENTRY_POINT_GROUP
    fake = [EntryPoint("3dgs", "splat_framework.methods.gaussian_splatting:spec_3dgs", group),
            EntryPoint("exits", "exits_on_import:spec", group), EntryPoint("interrupts", "interrupts_on_import:spec", group)]
    monkeypatch.setattr(plugins, "entry_points", lambda group: [e for e in fake if e.group == group])
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        methods = registry.discover_methods(config_dirs=[])
    assert list(methods) == ["3dgs"]
    lines = sorted(str(w.message) for w in caught)
    assert lines == ["method 'exits' of an installed package (exits_on_import:spec) failed to import "
                     "(SystemExit(0): it called sys.exit); ignored",
                     "method 'interrupts' of an installed package (interrupts_on_import:spec) failed to import "
                     "(KeyboardInterrupt); ignored"]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        with pytest.raises(DataError, match=r"^method 'exits' of an installed package .* \(SystemExit\(0\)"):
            registry.get_method("exits")
