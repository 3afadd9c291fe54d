"""Method registry, config variants and the training CLI's argument handling (no training)."""

import os
import resource
import subprocess
import sys
import warnings
from importlib.metadata import EntryPoint
from pathlib import Path

import pytest
from pydantic import ValidationError

from cli_harness import message_lines
from splat_framework import registry
from splat_framework.config import (
    DensifyConfig,
    SplatConfig,
    TrainConfig,
    apply_overrides,
    read_config_json,
    resolve_steps,
    save_config,
)
from splat_framework.errors import DataError
from support import REPO


def _fake_eps(monkeypatch, eps):
    from splat_framework import entry_points as plugins

    monkeypatch.setattr(plugins, "entry_points", lambda group: [e for e in eps if e.group == group])


def test_builtins_and_plugin_registered_through_entry_points():
    methods = registry.discover_methods()
    for name in ("3dgs", "3dgs-frustum", "3dgs-triang", "scgaussian", "scgaussian-single-stage", "scgaussian-hybrid",
                 "scgaussian-hybrid-rg", "scgaussian-hybrid-rg-dual", "scgaussian-only-ray",
                 "scgaussian-only-nonstructure"):
        assert name in methods, name
        cfg = methods[name].default_config()
        assert cfg.method == name  # variants never share a method name (no colliding outputs)


def test_broken_plugin_warns_instead_of_killing_the_cli(monkeypatch):
    eps = [
        EntryPoint("3dgs", "splat_framework.methods.gaussian_splatting:spec_3dgs", registry.ENTRY_POINT_GROUP),
        EntryPoint("broken", "no_such_module_xyz:spec", registry.ENTRY_POINT_GROUP),
    ]
    _fake_eps(monkeypatch, eps)
    with warnings.catch_warnings(record=True) as w:
        warnings.simplefilter("always")
        methods = registry.discover_methods(config_dirs=[])
    assert list(methods) == ["3dgs"]
    assert any("broken" in str(x.message) and "failed to import" in str(x.message) for x in w)


def test_registered_strategy_kinds_are_every_unnarrowed_methods(monkeypatch):
    """A StrategyConfig in group splat_framework.strategies under its kind's name is accepted by 3dgs
    (whose field is not narrowed) and written back in full; a broken or misnamed entry warns and is left out."""
    from scg_plugin.config import RayStrategyConfig
    from splat_framework.config import strategy_kinds
    from splat_framework.entry_points import STRATEGY_ENTRY_POINT_GROUP
    from splat_framework.methods.gaussian_splatting import spec_3dgs

    _fake_eps(monkeypatch, [
        EntryPoint("ray-gaussian", "scg_plugin.config:RayStrategyConfig", STRATEGY_ENTRY_POINT_GROUP),
        EntryPoint("misnamed", "scg_plugin.config:RayStrategyConfig", STRATEGY_ENTRY_POINT_GROUP),
        EntryPoint("broken", "no_such_module_xyz:Config", STRATEGY_ENTRY_POINT_GROUP),
    ])
    strategy_kinds.cache_clear()
    try:
        with warnings.catch_warnings(record=True) as w:
            warnings.simplefilter("always")
            assert strategy_kinds() == {"default": DensifyConfig, "ray-gaussian": RayStrategyConfig}
        assert sorted(m for m in ("misnamed", "broken") if any(m in str(x.message) for x in w)) == ["broken", "misnamed"]
        assert any("its kind tag is 'ray-gaussian', not its entry-point name 'misnamed'" in str(x.message) for x in w)
        base = spec_3dgs.default_config()
        cfg = apply_overrides(base, {"strategy": {"kind": "ray-gaussian", "prune_opa": 0.01}})
        assert type(cfg.strategy) is RayStrategyConfig and type(base).model_validate_json(cfg.model_dump_json()) == cfg
        with pytest.raises(ValidationError, match="unknown strategy kind 'mcmc'"):
            apply_overrides(base, {"strategy": {"kind": "mcmc"}})
    finally:
        strategy_kinds.cache_clear()


MY_METHODS = """
from splat_framework.plugin import MethodSpec, TrainConfig

ENTRY_POINTS = {"splat_framework.methods": {"my-3dgs": "my_methods:spec"}}

def config():
    return TrainConfig(method="my-3dgs")

spec = MethodSpec(name="my-3dgs", description="3DGS registered by SPLAT_PLUGINS", config_factory=config,
                  model="splat_framework.model.gaussians:GaussianModel")
"""
BROKEN_PLUGINS = {
    "no_table": "x = 1\n",
    "bad_group": "ENTRY_POINTS = {'splat_framework.method': {'a': 'm:b'}}\n",
    "bad_entries": "ENTRY_POINTS = {'splat_framework.methods': ['m:b']}\n",
    "raises": "raise RuntimeError('plugin broke')\n",
    "exits_0": "import sys\nsys.exit(0)\n",
    "exits_3": "import sys\nsys.exit(3)\n",
    "interrupts": "raise KeyboardInterrupt\n",
    "attribute": "import os\nos.no_such_function()\n",
    "empty_entry": "ENTRY_POINTS = {'splat_framework.methods': {'a': ''}}\n",
    "no_colon": "ENTRY_POINTS = {'splat_framework.methods': {'a': 'my_methods.spec'}}\n",
    "bad_name": "ENTRY_POINTS = {'splat_framework.methods': {'My Method': 'my_methods:spec'}}\n",
}


@pytest.mark.bad_input("`SPLAT_PLUGINS` naming something that is not a module name, a module that does not import "
                       "(whatever it raises: `sys.exit(0)`, `KeyboardInterrupt`, an `AttributeError`), or one without "
                       "a well-formed `ENTRY_POINTS` table (an entry `\"\"` or without a colon, a name that is not one); "
                       "`SPLAT_METHODS` set (no longer read)",
                       "exit 2, one line naming the variable, the module and what it raised (`--help` included)")
def test_a_method_registered_by_splat_plugins_trains_without_a_package(tmp_path):
    """A module on PYTHONPATH, named by ``SPLAT_PLUGINS``, declares a method in its ENTRY_POINTS as an
    installed package's entry points would: listed, trained, saved under its name; a bad module is
    one line naming the variable and the module."""
    from cli_harness import cli_env, run_cli

    code = tmp_path / "code"
    code.mkdir()
    (code / "my_methods.py").write_text(MY_METHODS)
    for name, text in BROKEN_PLUGINS.items():
        (code / f"{name}.py").write_text(text)
    path = os.pathsep.join(p for p in (str(code), os.environ.get("PYTHONPATH")) if p)
    env = cli_env(PYTHONPATH=path, SPLAT_PLUGINS="my_methods", SPLAT_COMPILE="0")
    listed = run_cli("train", "--help", code=0, env=env)
    assert "my-3dgs" in listed.stdout and "3DGS registered by SPLAT_PLUGINS" in listed.stdout
    out = tmp_path / "run"
    run_cli("train", "my-3dgs", "--data", "synthetic/forward-tiny", "--steps", "3", "--model.init.num-points", "200",
            "--no-progress", "--no-save-renders", "--output", out, code=0, env=env)
    assert read_config_json(out / "config.json").method == "my-3dgs" and (out / "metrics.json").is_file()
    for value, why in (("my methods", "entry 'my methods' is not a module name"),
                       ("no_such_module", "module 'no_such_module' cannot be imported"),
                       ("no_table", "has no ENTRY_POINTS"), ("bad_group", "names group 'splat_framework.method'"),
                       ("bad_entries", "is not a dict of name"),
                       ("raises", "cannot be imported (RuntimeError: plugin broke)"),
                       ("exits_0", "cannot be imported (SystemExit(0): it called sys.exit)"),
                       ("exits_3", "cannot be imported (SystemExit(3): it called sys.exit)"),
                       ("interrupts", "cannot be imported (KeyboardInterrupt)"),
                       ("attribute", "cannot be imported (AttributeError: module 'os' has no attribute"),
                       ("empty_entry", "ENTRY_POINTS['splat_framework.methods']['a']: '' is not a 'module:object' path"),
                       ("no_colon", "'my_methods.spec' is not a 'module:object' path"),
                       ("bad_name", "'My Method' is not a name")):
        run_cli("train", "my-3dgs", "--help", code=2, env={**env, "SPLAT_PLUGINS": value},
                match=(f"SPLAT_PLUGINS={value!r}: ", why), watch=[tmp_path])
    run_cli("train", "--help", code=2, env={**env, "SPLAT_PLUGINS": "exits_0"}, match="SystemExit(0)", watch=[tmp_path])
    run_cli("train", "--help", code=2, env={**env, "SPLAT_METHODS": "my_methods:spec"},
            match=("SPLAT_METHODS='my_methods:spec': no longer read; name a module in SPLAT_PLUGINS",), watch=[tmp_path])


def test_variant_files_override_base(tmp_path, monkeypatch):
    eps = [EntryPoint("3dgs", "splat_framework.methods.gaussian_splatting:spec_3dgs", registry.ENTRY_POINT_GROUP)]
    _fake_eps(monkeypatch, eps)
    (tmp_path / "small.toml").write_text('base = "3dgs"\ndescription = "d"\n[overrides.model]\nsh_degree = 1\n')
    (tmp_path / "smaller.toml").write_text('base = "small"\n[overrides.strategy]\nenabled = false\n')
    (tmp_path / "orphan.toml").write_text('base = "nope"\n')
    with warnings.catch_warnings(record=True) as w:
        warnings.simplefilter("always")
        methods = registry.discover_methods(config_dirs=[tmp_path])
    assert "orphan" not in methods and any("orphan" in str(x.message) for x in w)
    c = methods["smaller"].default_config()
    assert c.model.sh_degree == 1 and c.strategy.enabled is False and c.method == "smaller"
    assert methods["3dgs"].default_config().model.sh_degree == 3


def test_a_shipped_variant_keeps_its_name_and_a_broken_variant_package_warns(tmp_path, monkeypatch):
    """The packages' variants register before ``$SPLAT_CONFIG_PATH``'s: a user's file named like a shipped
    variant is refused with one warning naming both files, and the name keeps its meaning."""
    eps = [
        EntryPoint("3dgs", "splat_framework.methods.gaussian_splatting:spec_3dgs", registry.ENTRY_POINT_GROUP),
        EntryPoint("splat", "splat_configs", registry.CONFIG_ENTRY_POINT_GROUP),
        EntryPoint("gone", "no_such_package_xyz.configs", registry.CONFIG_ENTRY_POINT_GROUP),
    ]
    _fake_eps(monkeypatch, eps)
    (tmp_path / "3dgs-frustum.toml").write_text('base = "3dgs"\ndescription = "mine"\n')
    monkeypatch.setenv("SPLAT_CONFIG_PATH", str(tmp_path))
    with warnings.catch_warnings(record=True) as w:
        warnings.simplefilter("always")
        dirs = registry.default_config_dirs()
        methods = registry.discover_methods()
    assert dirs == [REPO / "configs", tmp_path]
    assert any("gone" in str(x.message) and "cannot be located" in str(x.message) for x in w)
    assert methods["3dgs-frustum"].description != "mine"
    shadowed = [str(x.message) for x in w if "already registered" in str(x.message)]
    assert shadowed == [f"config variant '3dgs-frustum' of {tmp_path / '3dgs-frustum.toml'} is already registered by "
                        f"{REPO / 'configs' / '3dgs-frustum.toml'}, which keeps it; ignored"]


def test_the_paper_rows_live_in_the_top_level_configs_folder():
    """``configs/`` holds every variant of the project, each describing its row in one line; no package of
    ``src/`` ships variants of its own."""
    import tomllib

    rows = sorted((REPO / "configs").glob("*.toml"))
    assert len(rows) >= 11 and not list((REPO / "src").glob("*/configs/*.toml"))
    for f in rows:
        doc = tomllib.loads(f.read_text())
        description = doc["description"]
        assert "\n" not in description and description.split(":")[0].startswith(("Paper", "Not a paper row")), f
    methods = registry.discover_methods()
    assert {f.stem for f in rows} <= set(methods)


def _listed_methods(help_text: str) -> list[str]:
    """The method and variant names of ``splat-train --help`` (its subcommand choices)."""
    import re

    block = help_text.partition("methods, each with its config variants under it")[2]
    assert block, help_text
    return sorted(re.findall(r"^ {2}(?: {4})?([a-z0-9][\w.-]*)(?: {2,}|$)", block, re.M))


@pytest.mark.slow
def test_variants_survive_a_wheel_install(tmp_path):
    """Built as a wheel and installed (not editable) into a fresh venv, ``splat-train --help`` lists exactly the
    methods and variants of the checkout.

    The fresh venv sees this environment's dependencies (torch, ...) through a .pth line, which does not
    run the editable install's own .pth, so splat itself comes from the wheel only."""
    import shutil
    import site
    import venv

    project = tmp_path / "project"  # a copy: setuptools writes build/ next to pyproject.toml
    for name in ("src", "configs"):
        shutil.copytree(REPO / name, project / name, ignore=shutil.ignore_patterns("*.egg-info", "__pycache__"))
    for name in ("pyproject.toml", "setup.py", "README.md", "LICENSE"):
        shutil.copy(REPO / name, project / name)
    built = subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "-q", "-w", str(tmp_path), str(project)],
                           capture_output=True, text=True, timeout=600)
    assert built.returncode == 0, built.stderr
    wheel = next(tmp_path.glob("splat_framework-*.whl"))
    env_dir = tmp_path / "venv"
    venv.create(env_dir, with_pip=False)
    py = env_dir / "bin" / "python"
    fresh_site = Path(subprocess.run([str(py), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
                                     capture_output=True, text=True, check=True).stdout.strip())
    (fresh_site / "deps.pth").write_text("\n".join(site.getsitepackages()) + "\n")
    subprocess.run([str(py), "-m", "pip", "install", "--no-deps", "--no-index", "-q", str(wheel)],
                   check=True, capture_output=True, timeout=300)
    env = {k: v for k, v in os.environ.items() if k not in ("SPLAT_CONFIG_PATH", "PYTHONPATH")}
    where = subprocess.run([str(py), "-c", "import scg_plugin, splat_configs; print(scg_plugin.__file__, splat_configs.__file__)"],
                           cwd=tmp_path, env=env, capture_output=True, text=True, check=True).stdout.split()
    assert all(w.startswith(str(fresh_site)) for w in where), where  # really the wheel's copy, not the checkout
    from splat_framework.render import _native

    native_dir = fresh_site / "splat_framework" / "render" / "native"
    assert all((native_dir / name).is_file() for name in _native._SOURCES)  # the native kernels' sources
    out = subprocess.run([str(env_dir / "bin" / "splat-train"), "--help"], cwd=tmp_path, env=env,
                         capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    here = subprocess.run([sys.executable, "-m", "splat_framework.cli.train", "--help"], env=env,
                          capture_output=True, text=True, timeout=120)
    assert _listed_methods(out.stdout) == _listed_methods(here.stdout)
    assert {f.stem for f in (REPO / "configs").glob("*.toml")} <= set(_listed_methods(out.stdout))


def test_bad_override_names_the_field():
    with pytest.raises(ValidationError, match="no_such_field"):
        apply_overrides(TrainConfig(), {"model": {"no_such_field": 1}})
    with pytest.raises(ValidationError, match="sh_degree"):
        apply_overrides(TrainConfig(), {"model": {"sh_degree": 7}})


def test_a_section_naming_another_kind_replaces_instead_of_merging():
    """The one merge rule and discriminated unions: editing a strategy merges into it; naming another
    kind starts from that kind's defaults (the old kind's fields would not validate)."""
    from splat_framework.config import deep_merge

    a = {"strategy": {"kind": "default", "reset_every": 5, "prune_opa": 0.1}, "seed": 1}
    assert deep_merge(a, {"strategy": {"reset_every": 7}})["strategy"] == {"kind": "default", "reset_every": 7, "prune_opa": 0.1}
    assert deep_merge(a, {"strategy": {"kind": "default", "reset_every": 7}})["strategy"]["prune_opa"] == 0.1
    assert deep_merge(a, {"strategy": {"kind": "mine", "every": 3}}) == {"strategy": {"kind": "mine", "every": 3}, "seed": 1}
    with pytest.raises(ValidationError, match="kind"):  # the framework's 3dgs lists only its own kind
        apply_overrides(TrainConfig(), {"strategy": {"kind": "ray-gaussian"}})
    assert type(apply_overrides(TrainConfig(), {"strategy": {"kind": "default"}}).strategy) is DensifyConfig


def test_every_config_field_has_a_docstring():
    from anchor_gs.config import ScaffoldTrainConfig
    from scg_plugin.config import SCGTrainConfig
    from splat_framework.cli.kinds import union_kinds

    def check(cls):
        for name, f in cls.model_fields.items():
            assert f.description, f"{cls.__name__}.{name} has no docstring"
            ann = f.annotation
            for member in [ann, *union_kinds(ann).values()]:  # a tagged union's kinds too (model.init)
                if isinstance(member, type) and issubclass(member, SplatConfig):
                    check(member)

    for cls in (TrainConfig, SCGTrainConfig, ScaffoldTrainConfig):
        check(cls)


def test_steps_rescale_the_whole_schedule():
    from scg_plugin.method import config_scgaussian

    c = resolve_steps(config_scgaussian().model_copy(update={"steps": 300}))
    assert c.total_steps == 300
    # scgaussian's own schedule is 1000 iterations: 500..1000 densification, no opacity reset,
    # 2000 warm-up iterations, SH degree raised every 1000, checkpoint every 1000.
    assert c.strategy.refine_start_iter == 150 and c.strategy.refine_stop_iter == 300
    assert c.strategy.reset_every is None and c.strategy.refine_every == 100  # refine_every is not rescaled
    with_reset = resolve_steps(config_scgaussian().model_copy(
        update={"steps": 300, "strategy": config_scgaussian().strategy.model_copy(update={"reset_every": 200})}))
    assert with_reset.strategy.reset_every == 60  # an optional period rescales like any other
    assert c.model.warmup_steps == 600 and c.model.sh_degree_interval == 300
    assert c.checkpoint_every == 300
    # a per-step factor (StepFactor) keeps its product over the run: 0.99 per step over 1000 is 0.99^(10/3) over 300
    assert c.strategy.opacity_decay == pytest.approx(0.99 ** (1000 / 300))
    same = resolve_steps(TrainConfig())
    assert same.strategy.refine_stop_iter == DensifyConfig().refine_stop_iter


def test_more_views_than_the_schedule_is_written_for_scale_it():
    """scgaussian's schedule is written for 3 views: 6 train twice as long, 5 five thirds; --steps and --views all keep their meaning."""
    from scg_plugin.method import config_scgaussian

    base = config_scgaussian()
    assert base.schedule_views == 3
    for views in (2, 3):
        same = base.model_copy(update={"views": views})
        assert resolve_steps(same) == same and same.total_steps == 1000
    six = resolve_steps(base.model_copy(update={"views": 6}))
    assert six.total_steps == 2000 and six.strategy.refine_stop_iter == 2000
    assert six.strategy.reset_every is None and six.model.warmup_steps == 4000
    assert six.strategy.refine_start_iter == 500  # a start (StartSteps) does not grow with the run
    assert six.model.sh_degree_interval == 1000  # nor the SH degree's period (RampPeriod): degree 1 from 1000
    assert six.strategy.opacity_decay == pytest.approx(0.99 ** 0.5)  # half the decay per step over twice the steps
    assert six == resolve_steps(base.model_copy(update={"views": 6, "steps": 2000}))
    assert resolve_steps(six) == six  # a resumed run resolves to the same schedule
    assert [resolve_steps(base.model_copy(update={"views": v})).total_steps for v in (4, 5, 8)] == [1333, 1667, 2667]
    assert resolve_steps(base.model_copy(update={"views": 8, "steps": 500})).total_steps == 500
    assert resolve_steps(base.model_copy(update={"views": "all"})).total_steps == 1000
    short = base.model_copy(update={"views": 6, "default_steps": 40})  # a test's short schedule stays short
    assert resolve_steps(short).total_steps == 80
    assert resolve_steps(TrainConfig(views=40)).total_steps == 3000  # 3dgs: no rule


def test_start_steps_shrink_with_a_shorter_run_and_stay_with_a_longer_one():
    """scale_schedule: a StartSteps field (densification's first iteration) or a RampPeriod (the SH
    degree's) follows a compressed schedule but keeps its value in a stretched one; plain Steps fields
    follow both."""
    from splat_framework.config import scale_schedule

    base = TrainConfig()  # 3dgs: refine_start_iter 500, refine_stop_iter 2500
    short, long = scale_schedule(base, 0.5), scale_schedule(base, 3.0)
    assert (short.strategy.refine_start_iter, short.strategy.refine_stop_iter) == (250, 1250)
    assert (long.strategy.refine_start_iter, long.strategy.refine_stop_iter) == (500, 7500)
    assert (short.model.sh_degree_interval, long.model.sh_degree_interval) == (250, 500)  # RampPeriod
    assert resolve_steps(base.model_copy(update={"steps": 6000})).strategy.refine_start_iter == 500
    decaying = base.model_copy(update={"strategy": base.strategy.model_copy(update={"opacity_decay": 0.9})})
    assert scale_schedule(decaying, 0.5).strategy.opacity_decay == pytest.approx(0.81)  # StepFactor: a power
    assert scale_schedule(decaying, 2.0).strategy.opacity_decay == pytest.approx(0.9 ** 0.5)
    assert scale_schedule(base, 2.0).strategy.opacity_decay == 1.0  # off stays off


def test_the_users_own_iteration_counts_keep_their_numbers_when_the_schedule_is_rescaled():
    """resolve_steps with the defaults the user's settings were applied to: a Steps, Period or
    StepFactor field that differs from them is the user's and stays as set; the ones left at their
    defaults follow --steps; another strategy kind is compared with its own class's defaults."""
    from splat_framework.config import DensifyConfig

    class Another(DensifyConfig):  # a kind of the user's, with its own defaults
        refine_start_iter: int = 400  # a StartSteps no longer: never rescaled

    defaults = TrainConfig()  # 3dgs at 3000: checkpoint_every 1000, refine_stop_iter 2500
    typed = defaults.model_copy(update={
        "steps": 300, "checkpoint_every": 5,
        "strategy": defaults.strategy.model_copy(update={"refine_stop_iter": 2000, "opacity_decay": 0.9}),
    })
    got = resolve_steps(typed, defaults)
    assert (got.checkpoint_every, got.strategy.refine_stop_iter, got.strategy.opacity_decay) == (5, 2000, 0.9)
    assert got.strategy.refine_start_iter == 50 and got.total_steps == 300  # left at its default: rescaled
    assert resolve_steps(typed).checkpoint_every == 1  # without the defaults: everything rescales
    assert resolve_steps(got, defaults) == got  # a resolved config resolves to itself
    other = typed.model_copy(update={"strategy": Another(refine_stop_iter=2000)})
    kept = resolve_steps(other, defaults).strategy
    assert (kept.refine_stop_iter, kept.refine_start_iter) == (2000, 400)
    assert kept.reset_every == 300  # its own default (3000): rescaled


def test_config_json_roundtrip_with_schema_version(tmp_path):
    from scg_plugin.method import config_scgaussian

    cfg = config_scgaussian()
    save_config(cfg, tmp_path / "config.json")
    method, raw, _ = read_config_json(tmp_path / "config.json")
    assert method == "scgaussian"
    assert type(cfg).model_validate(raw) == cfg
    (tmp_path / "old.json").write_text('{"schema_version": 0, "config": {}}')
    with pytest.raises(DataError, match="schema version"):
        read_config_json(tmp_path / "old.json")


def test_help_is_fast_and_lists_methods():
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    r = subprocess.run([sys.executable, "-m", "splat_framework.cli.train", "--help"], capture_output=True, text=True, timeout=60)
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    assert r.returncode == 0
    assert "scgaussian" in r.stdout and "3dgs-triang" in r.stdout and "octree-gs-triang" in r.stdout
    assert "import" not in r.stderr
    assert cpu < 5.0  # CPU seconds of the child (about 1.5 s), not wall time: a loaded machine does not change it
    r = subprocess.run([sys.executable, "-c", "import sys, splat_framework.cli.train as t; t.build_parser_type(); print('torch' in sys.modules)"], capture_output=True, text=True, timeout=60)
    assert r.stdout.strip() == "False"  # building --help never imports torch


def test_method_help_shows_field_docstrings():
    r = subprocess.run([sys.executable, "-m", "splat_framework.cli.train", "scgaussian", "--help"], capture_output=True, text=True, timeout=60)
    assert r.returncode == 0
    for flag in ("--data", "--views", "--downscale", "--steps", "--output", "--seed", "--device", "--model.lambda-rg"):
        assert flag in r.stdout, flag
    assert "rendering-geometry" in r.stdout


def test_bad_cli_values_exit_2_with_one_line(tmp_path):
    r = subprocess.run(
        [sys.executable, "-m", "splat_framework.cli.train", "3dgs", "--data", str(tmp_path / "missing"), "--output", str(tmp_path / "run")],
        capture_output=True, text=True, timeout=120,
    )
    assert r.returncode == 2, r.stderr
    assert len(message_lines(r.stderr)) == 1 and "missing" in r.stderr and "Traceback" not in r.stderr


@pytest.mark.parametrize("args, field", [
    (["--steps", "0"], "steps"),
    (["--steps", "-5"], "steps"),
    (["--model.init.num-points", "-5"], "model.init.num_points"),
    (["--model.init.num-points", "0"], "model.init.num_points"),
    (["--checkpoint-every", "-1"], "checkpoint_every"),
    (["--optim.sh0-lr", "nan"], "sh0_lr"),
    (["--optim.sh0-lr", "-1"], "sh0_lr"),
    (["--optim.sh0-lr", "1e39"], "sh0_lr"),
    (["--strategy.reset-every", "0"], "reset_every"),
    (["--device", "bogus"], "device"),
    (["--device", "cuda:7"], "cuda:7"),
])
@pytest.mark.bad_input("numbers out of range (`--steps 0`, `--model.init.num-points -5`, a NaN learning rate, ...), unknown devices", "exit 2, one line naming the field and its range")
def test_out_of_range_numbers_and_devices_exit_2_naming_the_field(tmp_path, args, field):
    r = subprocess.run(
        [sys.executable, "-m", "splat_framework.cli.train", "3dgs", "--data", "synthetic/forward-tiny",
         "--output", str(tmp_path / "run"), "--no-progress", *args],
        capture_output=True, text=True, timeout=300,
    )
    assert r.returncode == 2, (r.returncode, r.stderr[-2000:])
    assert len(message_lines(r.stderr)) == 1 and field in r.stderr and "Traceback" not in r.stderr, r.stderr
    assert not (tmp_path / "run").exists()  # rejected before anything is written


def test_invalid_values_of_nested_configs_name_their_dotted_path(tmp_path):
    """Without tyro's private hooks: a config built from arguments raises InvalidArguments (not a
    ValueError, which tyro would box), and the CLI finds where that config class sits."""
    from scg_plugin.config import RayStrategyConfig, SCGModelConfig
    from splat_framework.cli.common import config_path
    from splat_framework.config import GaussianModelConfig, InvalidArguments, MatchConfig, OptimConfig, cli_parsing

    assert config_path(TrainConfig) == "" and config_path(GaussianModelConfig) == "model"
    assert config_path(SCGModelConfig) == "model" and config_path(MatchConfig) == "model.matching"
    assert (config_path(DensifyConfig), config_path(RayStrategyConfig), config_path(OptimConfig)) == ("strategy",) * 2 + ("optim",)
    with pytest.raises(ValidationError):
        MatchConfig(max_matches=-3)  # outside a CLI: pydantic's own error
    with cli_parsing(), pytest.raises(InvalidArguments) as e:
        MatchConfig(max_matches=-3)
    assert e.value.config_cls is MatchConfig and not isinstance(e.value, ValueError)
    r = subprocess.run(
        [sys.executable, "-m", "splat_framework.cli.train", "scgaussian", "--data", "synthetic/forward-tiny",
         "--output", str(tmp_path / "run"), "--model.matching.max-matches", "-3"],
        capture_output=True, text=True, timeout=300,
    )
    assert r.returncode == 2 and len(message_lines(r.stderr)) == 1, r.stderr
    assert r.stderr.startswith("error: invalid config: model.matching.max_matches: "), r.stderr
    assert not (tmp_path / "run").exists()
    private = [p for p in (REPO / "src").rglob("*.py") if "tyro._" in p.read_text()]
    assert not private, f"imports of tyro's private modules: {private}"


def test_scgaussian_may_start_from_rays_only_and_ranges_hold_in_toml_overrides():
    from scg_plugin.method import config_scgaussian

    assert apply_overrides(config_scgaussian(), {"model": {"init": {"num_points": 0}}}).model.init.num_points == 0
    with pytest.raises(ValidationError, match="num_points"):
        apply_overrides(config_scgaussian(), {"model": {"init": {"num_points": -5}}})
    with pytest.raises(ValidationError, match="z_lr"):
        apply_overrides(config_scgaussian(), {"model": {"z_lr": float("nan")}})


@pytest.mark.bad_input("a TOML variant with a wrong type, a syntax error, a circular `base`", "one warning line naming the file and field; other methods unaffected; exit 2 only when that variant is asked for")
def test_broken_variants_warn_in_one_line_and_fail_only_when_asked_for(tmp_path, monkeypatch):
    """A variant with a wrong type, a TOML syntax error or a circular base: one warning line each naming
    the file, every other method still works (``--help`` included), and asking for the broken variant
    exits 2 with one line naming the file and the field."""
    (tmp_path / "bad-type.toml").write_text('base = "3dgs"\n[overrides.model]\nsh_degree = "three"\n')
    (tmp_path / "bad-syntax.toml").write_text('base = "3dgs"\n[overrides\nsteps = 3\n')
    (tmp_path / "loop-a.toml").write_text('base = "loop-b"\n')
    (tmp_path / "loop-b.toml").write_text('base = "loop-a"\n')
    (tmp_path / "not-a-table.toml").write_text('base = "3dgs"\noverrides = 3\n')
    env = {**os.environ, "SPLAT_CONFIG_PATH": str(tmp_path)}

    def cli(*args):
        return subprocess.run([sys.executable, "-m", "splat_framework.cli.train", *args], capture_output=True,
                              text=True, timeout=120, env=env)

    r = cli("--help")
    assert r.returncode == 0 and "scgaussian" in r.stdout and "bad-type" not in r.stdout
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 5 and all(x.startswith("warning: ") for x in lines), r.stderr
    for name in ("bad-type.toml", "bad-syntax.toml", "loop-a.toml", "loop-b.toml", "not-a-table.toml"):
        assert sum(name in x for x in lines) == 1, (name, r.stderr)
    assert any("bad-type.toml" in x and "model.sh_degree" in x for x in lines)
    r = cli("3dgs", "--help")
    assert r.returncode == 0 and "--model.sh-degree" in r.stdout
    r = cli("bad-type", "--data", "synthetic/forward-tiny", "--output", str(tmp_path / "run"))
    assert r.returncode == 2
    err = r.stderr.strip().splitlines()
    assert err[-1].startswith("error: ") and "bad-type.toml" in err[-1] and "model.sh_degree" in err[-1], r.stderr
    assert "Traceback" not in r.stderr and not (tmp_path / "run").exists()
    monkeypatch.setenv("SPLAT_CONFIG_PATH", str(tmp_path))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", registry.VariantWarning)
        assert registry.get_method("3dgs").name == "3dgs"
        with pytest.raises(DataError, match="bad-type.toml.*model.sh_degree"):
            registry.get_method("bad-type")


def test_a_cli_run_looks_its_method_up_once(tmp_path, monkeypatch):
    from splat_framework.cli import train as cli_train

    calls = []
    real = registry.discover_methods

    def counted(*args, **kwargs):
        calls.append(1)
        return real(*args, **kwargs)

    monkeypatch.setattr(registry, "discover_methods", counted)
    run = ["3dgs", "--data", "synthetic/forward-tiny", "--steps", "4", "--output", str(tmp_path / "run"),
           "--no-progress", "--no-save-renders", "--model.init.num-points", "200"]
    cli_train.main(run)
    assert len(calls) == 1  # parsing; the trainer gets the spec instead of asking the registry again
    calls.clear()
    cli_train.main([*run, "--resume"])  # a resume checks config.json against the same spec
    assert len(calls) == 1
