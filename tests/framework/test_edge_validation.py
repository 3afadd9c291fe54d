"""Validation at the edge (issue 40, item 5): every config float is finite, every config count is
bounded, every device field goes through the ``--device`` resolver, checkpoints are checked (step in
range, finite values) before use with fallback to the previous good one, TOML variants never break
discovery, and tyro's parse errors are one line. Walks every registered method's config and every
SplatConfig subclass, so a field added later is checked too."""

from __future__ import annotations

import hashlib
import io
import math
import os
import shutil
import warnings
from pathlib import Path

import pytest
import torch
from pydantic import ValidationError

from cli_harness import cli_env, message_lines, run_cli
from config_walk import DEFAULTS, FIELDS, METHODS, members, nested
from splat_framework import registry
from splat_framework.cli.common import format_validation_error, tyro_error_line
from splat_framework.config import MAX_STEPS, SplatConfig, apply_overrides
from splat_framework.devices import device_fields, resolve_config_devices
from splat_framework.engine.checkpoint import (
    MAGIC,
    check_structure,
    checkpoint_path,
    list_checkpoints,
    load_checkpoint,
    load_latest,
)
from splat_framework.errors import CheckpointError, DataError

HUGE = 10**18
NOT_FINITE = (math.inf, -math.inf, math.nan)
FLOAT_FIELDS = sorted({(m, p) for m, p, t in FIELDS if float in t})
INT_FIELDS = sorted({(m, p) for m, p, t in FIELDS if int in t})


def _subclasses(cls) -> set[type]:
    return {c for s in cls.__subclasses__() for c in (s, *_subclasses(s))}


def _constructible(cls) -> bool:
    """Whether ``cls()`` builds (abstract bases with a required tag do not: their subclasses are checked)."""
    try:
        cls()
    except ValidationError:
        return False
    return True


OUR_CONFIG_CLASSES = sorted(
    (c for c in _subclasses(SplatConfig)
     if c.__module__.split(".")[0] in {"splat_framework", "scg_plugin", "anchor_gs"} and _constructible(c)),
    key=lambda c: f"{c.__module__}.{c.__qualname__}",
)


def _rejected(method: str, path: tuple, value) -> str:
    """The one-line error of ``method``'s config with ``path`` set to ``value`` (fails if accepted)."""
    with pytest.raises(ValidationError) as e:
        apply_overrides(DEFAULTS[method], nested(path, value))
    line = format_validation_error(e.value)
    assert "\n" not in line and ".".join(path) in line, line
    return line


# ------------------------------------------------------------------ floats, counts
@pytest.mark.parametrize("method", sorted(METHODS))
@pytest.mark.bad_input("`inf` or `nan` in any float of any config (`--model.lambda-rg inf`, matching thresholds)", "exit 2, one line naming the field")
def test_every_float_field_of_every_method_refuses_inf_and_nan(method):
    paths = [p for m, p in FLOAT_FIELDS if m == method]
    assert paths, method
    for path in paths:
        for value in NOT_FINITE:
            assert "finite" in _rejected(method, path, value)


@pytest.mark.parametrize("method", sorted(METHODS))
@pytest.mark.bad_input("huge counts (`--model.feat-dim 1000000000`, 10^18 in any int field)", "exit 2, one line naming the field and its bound; what RAM cannot hold is refused by the memory plan before any allocation")
def test_every_count_of_every_method_has_an_upper_bound(method):
    """feat_dim 10^9 (anchor_gs) tried to allocate 33 TB: every int field now has a documented bound."""
    paths = [p for m, p in INT_FIELDS if m == method]
    assert paths, method
    for path in paths:
        _rejected(method, path, HUGE)


@pytest.mark.parametrize("cls", OUR_CONFIG_CLASSES, ids=lambda c: c.__qualname__)
@pytest.mark.bad_input("`inf` or `nan` in any float of any config (`--model.lambda-rg inf`, matching thresholds)", "exit 2, one line naming the field")
def test_every_config_class_refuses_non_finite_floats_and_unbounded_counts(cls):
    """Classes no registered method uses by default (other strategy kinds...) follow the same rules."""
    for name, info in cls.model_fields.items():
        types = members(info.annotation)
        bad = [*NOT_FINITE] if float in types else [HUGE] if int in types else []
        for value in bad:
            with pytest.raises(ValidationError, match=name):
                cls(**{name: value})


# ------------------------------------------------------------------ devices
@pytest.mark.bad_input("an unknown device in any device field (`--model.matching.device nosuch`)", "exit 2, one line, no run folder")
def test_every_device_field_goes_through_the_device_resolver():
    cfg = DEFAULTS["scgaussian"]
    assert dict(device_fields(cfg)) == {"device": "cpu", "model.matching.device": "cpu"}
    bad = apply_overrides(cfg, {"model": {"matching": {"device": "nosuchdevice"}}})
    with pytest.raises(DataError, match=r"^--model\.matching\.device: 'nosuchdevice' is not a torch device"):
        resolve_config_devices(bad)
    with pytest.raises(DataError, match=r"^run/config.json: model\.matching\.device"):
        resolve_config_devices(bad, "run/config.json")
    with pytest.raises(ValidationError, match="model.matching.device"):  # spelling checked torch-free, at parse time
        apply_overrides(cfg, {"model": {"matching": {"device": "cuda:x"}}})


# ------------------------------------------------------------------ checkpoints
def _write_raw(path: Path, payload: dict) -> Path:
    """``payload`` as a checkpoint file with a valid checksum, bypassing save_checkpoint's own checks."""
    buf = io.BytesIO()
    torch.save(payload, buf)
    data = buf.getvalue()
    path.write_bytes(MAGIC + hashlib.sha256(data).hexdigest().encode() + b"\n" + data)
    return path


def _nan(params: dict) -> dict:
    out = dict(params)
    out["means"] = out["means"].clone()
    out["means"][0, 0] = float("nan")
    return out


@pytest.fixture
def run_copy(run_dir, tmp_path):
    """A copy of the shared tiny 30-iteration run whose only checkpoint is step 20's (its final state,
    relabelled), so that a newer file of the run's range (30) can be damaged."""
    out = tmp_path / "run"
    shutil.copytree(run_dir, out)
    folder = out / "checkpoints"
    last = list_checkpoints(folder)[-1]
    ck = load_checkpoint(last)
    for p in list_checkpoints(folder):
        p.unlink()
    _write_raw(checkpoint_path(folder, 20), {**ck, "step": 20})
    return out


BAD_CHECKPOINTS = {  # name -> (file step, payload edit)
    "step -7": (30, lambda ck: {**ck, "step": -7}),
    "step 10^12": (10**12, lambda ck: {**ck, "step": 10**12}),
    "step not its name's": (30, lambda ck: {**ck, "step": 25}),
    "step past the run's end": (31, lambda ck: {**ck, "step": 31}),  # the run has 30 iterations
    "NaN parameters": (30, lambda ck: {**ck, "step": 30, "params": _nan(ck["params"])}),
}


@pytest.mark.parametrize("case", sorted(BAD_CHECKPOINTS))
@pytest.mark.bad_input("a checkpoint with step -7 or 10^12, a step past the run's end, or NaN parameters under a valid checksum", "one warning line, the previous good checkpoint is used")
def test_a_checkpoint_with_a_bad_step_or_nan_values_falls_back_to_the_previous(run_copy, case):
    """A valid checksum proves the bytes, not the values: step -7 or 10^12 and NaN parameters are refused
    in one line naming the file, and the previous good checkpoint is used."""
    from splat_framework.engine.run import load_trained_model

    folder = run_copy / "checkpoints"
    good = list_checkpoints(folder)[-1]
    step, edit = BAD_CHECKPOINTS[case]
    bad = _write_raw(checkpoint_path(folder, step), edit(load_checkpoint(good)))
    with pytest.raises(CheckpointError) as e:
        check_structure(bad, load_checkpoint(bad), max_step=30)
    assert str(bad) in str(e.value) and "\n" not in str(e.value)
    msgs = []
    assert load_latest(folder, report=msgs.append, accept=lambda p, ck: check_structure(p, ck, max_step=30))[0] == good
    assert len(msgs) == 1 and bad.name in msgs[0] and "previous checkpoint" in msgs[0]
    with pytest.warns(UserWarning, match=f"{bad.name}.*previous checkpoint"):  # eval, render, export, view
        load_trained_model(run_copy)


@pytest.mark.bad_input("a checkpoint with step -7 or 10^12, a step past the run's end, or NaN parameters under a valid checksum", "one warning line, the previous good checkpoint is used")
def test_resume_skips_a_nan_checkpoint(run_copy, capsys):
    from splat_framework.config import read_config_json
    from splat_framework.engine.trainer import Trainer

    folder = run_copy / "checkpoints"
    good = list_checkpoints(folder)[-1]
    ck = load_checkpoint(good)
    _write_raw(checkpoint_path(folder, 30), {**ck, "step": 30, "params": _nan(ck["params"])})
    method, raw, _ = read_config_json(run_copy / "config.json")
    cfg = type(DEFAULTS[method]).model_validate({**raw, "resume": True, "overwrite": False, "output": str(run_copy),
                                                 "progress": False})
    capsys.readouterr()
    trainer = Trainer(cfg)
    assert trainer.restore() and trainer.start_step == 20
    lines = [ln for ln in capsys.readouterr().err.splitlines() if "step-0000030.ckpt" in ln]
    assert len(lines) == 1 and "non-finite" in lines[0], lines


@pytest.mark.bad_input("a checkpoint with step -7 or 10^12, a step past the run's end, or NaN parameters under a valid checksum", "one warning line, the previous good checkpoint is used")
def test_cli_export_falls_back_from_a_nan_checkpoint_with_one_warning_line(run_copy, tmp_path):
    folder = run_copy / "checkpoints"
    ck = load_checkpoint(list_checkpoints(folder)[-1])
    bad = _write_raw(checkpoint_path(folder, 30), {**ck, "step": 30, "params": _nan(ck["params"])})
    out = tmp_path / "g.ply"
    r = run_cli("export", run_copy, "--out", out, code=0, watch=[tmp_path], allowed=[out])
    warned = message_lines(r.stderr)
    assert len(warned) == 1 and bad.name in warned[0] and "non-finite" in warned[0], r.stderr
    assert out.is_file()


# ------------------------------------------------------------------ TOML variants
def _discover(folder: Path) -> tuple[dict, list[str]]:
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        methods = registry.discover_methods([folder])
    return methods, [str(w.message) for w in caught]


VARIANT_FILES = {
    "binary": (b"\x89PNG\r\n\x1a\n\x00\xff\xfe" + bytes(range(256)), "not UTF-8"),
    "utf-16": ('base = "3dgs"\n[overrides]\n'.encode("utf-16"), "not UTF-8"),
    "syntax error": (b'base = "3dgs"\nx = [1, 2\n', "TOML syntax error"),
    "infinite weight": (b'base = "3dgs"\n[overrides.model]\nlambda_dssim = inf\n', "finite"),
}


@pytest.mark.parametrize("case", sorted(VARIANT_FILES))
@pytest.mark.bad_input("a binary, UTF-16 or oversized `.toml`, or a FIFO or folder named `*.toml`, in `$SPLAT_CONFIG_PATH`", "`--help` and every command work; one warning line per file; special files are never opened")
def test_a_bad_variant_file_is_one_warning_line(tmp_path, case):
    blob, needle = VARIANT_FILES[case]
    (tmp_path / "bad.toml").write_bytes(blob)
    methods, msgs = _discover(tmp_path)
    assert "3dgs" in methods and "bad" not in methods
    assert len(msgs) == 1 and "bad.toml" in msgs[0] and needle in msgs[0] and "\n" not in msgs[0], msgs
    assert registry.left_out("bad") == msgs[0].removesuffix("; ignored")


@pytest.mark.bad_input("a binary, UTF-16 or oversized `.toml`, or a FIFO or folder named `*.toml`, in `$SPLAT_CONFIG_PATH`", "`--help` and every command work; one warning line per file; special files are never opened")
def test_special_files_named_toml_are_never_opened(tmp_path):
    os.mkfifo(tmp_path / "fifo.toml")  # opening it for reading would block forever
    (tmp_path / "folder.toml").mkdir()
    (tmp_path / "link.toml").symlink_to(tmp_path / "fifo.toml")
    methods, msgs = _discover(tmp_path)
    assert "3dgs" in methods
    assert sorted(m.split(":")[0] for m in msgs) == sorted(str(tmp_path / f) for f in ("fifo.toml", "folder.toml", "link.toml"))
    assert all("not a regular file" in m for m in msgs), msgs


@pytest.mark.bad_input("a TOML variant with a wrong type, a syntax error, a circular `base`", "one warning line naming the file and field; other methods unaffected; exit 2 only when that variant is asked for")
def test_circular_bases_are_one_line_per_file_naming_the_cycle(tmp_path):
    (tmp_path / "a.toml").write_text('base = "b"\n[overrides]\n')
    (tmp_path / "b.toml").write_text('base = "a"\n[overrides]\n')
    (tmp_path / "c.toml").write_text('base = "c"\n[overrides]\n')
    methods, msgs = _discover(tmp_path)
    assert not {"a", "b", "c"} & set(methods)
    assert len(msgs) == 3 and all("\n" not in m for m in msgs), msgs
    assert "a -> b -> a" in registry.left_out("a") and "c -> c" in registry.left_out("c")


# ------------------------------------------------------------------ the command line
@pytest.mark.bad_input("a binary, UTF-16 or oversized `.toml`, or a FIFO or folder named `*.toml`, in `$SPLAT_CONFIG_PATH`", "`--help` and every command work; one warning line per file; special files are never opened")
def test_splat_train_help_survives_binary_utf16_and_fifo_variants(tmp_path):
    (tmp_path / "binary.toml").write_bytes(VARIANT_FILES["binary"][0])
    (tmp_path / "utf16.toml").write_bytes(VARIANT_FILES["utf-16"][0])
    os.mkfifo(tmp_path / "fifo.toml")
    r = run_cli("train", "--help", code=0, env=cli_env(SPLAT_CONFIG_PATH=str(tmp_path)), timeout=60, watch=[tmp_path])
    lines = [ln for ln in r.stderr.splitlines() if ln.strip()]
    assert len(lines) == 3 and all(ln.startswith("warning: ") for ln in lines), r.stderr  # one a file
    assert "usage: splat-train" in r.stdout


@pytest.mark.parametrize("case", ["syntax error", "circular"])
@pytest.mark.bad_input("a TOML variant with a wrong type, a syntax error, a circular `base`", "one warning line naming the file and field; other methods unaffected; exit 2 only when that variant is asked for")
def test_asking_for_a_broken_variant_is_one_line_naming_its_file(tmp_path, case):
    if case == "circular":
        (tmp_path / "bad.toml").write_text('base = "other"\n[overrides]\n')
        (tmp_path / "other.toml").write_text('base = "bad"\n[overrides]\n')
    else:
        (tmp_path / "bad.toml").write_bytes(VARIANT_FILES["syntax error"][0])
    run_cli("train", "bad", "--steps", "1", "--output", tmp_path / "run", code=2,
            match=(str(tmp_path / "bad.toml"), "circular" if case == "circular" else "syntax"),
            env=cli_env(SPLAT_CONFIG_PATH=str(tmp_path)), timeout=60, watch=[tmp_path])


BAD_ARGUMENTS = {  # issue 40's cases, in a subprocess -> what the one line says
    "infinite loss weight": (["scgaussian", "--model.lambda-rg", "inf"], "model.lambda_rg: Input should be a finite number"),
    "huge count": (["scaffold-gs", "--model.feat-dim", "1000000000"], "model.feat_dim: Input should be less than or equal to 1024"),
    "views abc": (["3dgs", "--views", "abc"], "--views: expected {None}|INT|{all}, got ['abc']"),
    "unknown method": (["3dgx", "--steps", "1"], "unknown method '3dgx' (did you mean '3dgs'?)"),
    "mistyped flag": (["3dgs", "--dta", "x"], "unrecognized arguments: --dta x (did you mean '--data'?); see splat-train --help"),
    "bad choice": (["3dgs", "--format", "llf"], "--format: 'llf' is not one of auto, llff, blender, dtu, transforms, colmap (did you mean 'llff'?)"),
    "unavailable matching device": (["scgaussian", "--model.matching.device", "nosuchdevice", "--data", "synthetic/forward-tiny"],
                                    "--model.matching.device: 'nosuchdevice' is not a torch device"),
}


@pytest.mark.parametrize("case", sorted(BAD_ARGUMENTS))
@pytest.mark.bad_input("`inf` or `nan` in any float of any config (`--model.lambda-rg inf`, matching thresholds)", "exit 2, one line naming the field")
@pytest.mark.bad_input("`--views abc`, an unknown method (`3dgx`), a bad choice (`--format llf`), an unknown flag", "exit 2, one line (with \"did you mean\" where one is close)")
def test_bad_train_arguments_are_one_line(tmp_path, case):
    args, needle = BAD_ARGUMENTS[case]
    r = run_cli("train", *args, "--output", tmp_path / "run", code=2, match=needle, watch=[tmp_path])
    assert not (tmp_path / "run").exists() and r.message.startswith("error: ")


OTHER_BAD_ARGUMENTS = {  # tyro's other error kinds, in-process (the same main as the subprocess runs)
    "nan threshold": (["scgaussian", "--model.matching.magsac-threshold", "nan"], "magsac_threshold"),
    "unknown flag": (["3dgs", "--bogus", "3"], "unrecognized arguments: --bogus 3; see splat-train --help"),
    "mistyped flags": (["scgaussian", "--stpes", "3", "--model.matching.magsac-treshold=2"],
                       "unrecognized arguments: --stpes 3 --model.matching.magsac-treshold=2 (did you mean '--steps' "
                       "for --stpes, '--model.matching.magsac-threshold' for --model.matching.magsac-treshold?)"),
    "unknown method in capitals": (["3DGX"], "unknown method '3DGX' (did you mean '3dgs'?); splat-train --help lists them"),
    "missing value": (["3dgs", "--steps"], "--steps"),
    "no method": ([], "missing a command: expected one of {3dgs"),
    "fractional count": (["3dgs", "--model.init.num-points", "1.5"], "--model.init.num-points: invalid literal for int()"),
}


@pytest.mark.parametrize("case", sorted(OTHER_BAD_ARGUMENTS))
@pytest.mark.bad_input("`--views abc`, an unknown method (`3dgx`), a bad choice (`--format llf`), an unknown flag", "exit 2, one line (with \"did you mean\" where one is close)")
def test_other_parse_errors_are_one_line(case, capsys):
    from splat_framework.cli.common import ArgumentsError
    from splat_framework.cli.train import main
    from splat_framework.config import InvalidArguments

    args, needle = OTHER_BAD_ARGUMENTS[case]
    with pytest.raises((ArgumentsError, InvalidArguments)) as e:
        main(args)
    assert needle in str(e.value) and "\n" not in str(e.value if isinstance(e.value, ArgumentsError) else
                                                       format_validation_error(e.value.error))
    assert capsys.readouterr().err == ""  # tyro's box was not printed


def test_a_method_is_named_in_any_letter_case():
    """``splat-train 3DGS``: 3dgs's own command line (its parse error, not an unknown method), and
    the config of 3dgs; a variant's name too."""
    from splat_framework.cli.common import ArgumentsError
    from splat_framework.cli.train import main, method_named

    with pytest.raises(ArgumentsError, match=r"^--views: expected .*; see splat-train --help$"):
        main(["3DGS", "--views", "abc"])
    methods = {"3dgs": None, "3dgs-triang": None, "scgaussian": None}
    assert method_named(["3DGS-Triang", "--steps", "1"], "3DGS-Triang", methods) == (["3dgs-triang", "--steps", "1"], "3dgs-triang")
    assert method_named(["scgaussian"], "scgaussian", methods) == (["scgaussian"], "scgaussian")


@pytest.mark.bad_input("`--views abc`, an unknown method (`3dgx`), a bad choice (`--format llf`), an unknown flag", "exit 2, one line (with \"did you mean\" where one is close)")
def test_tyro_error_boxes_become_one_line():
    """The box parser on tyro's own layout (wrapped lines, rules), independent of the terminal width."""
    box = ("╭─ Value error ──────────╮\n│ Error parsing --views: no type matching INT|{all} could be │\n"
           "│ instantiated from ['abc'].                                   │\n│                │\n│ Got errors: │\n"
           "│ - int: invalid literal │\n│ ────────────── │\n│ Argument helptext: │\n╰──────────╯\n")
    assert tyro_error_line(box, "splat-train") == "--views: expected INT|{all}, got ['abc']; see splat-train --help"
    ascii_box = (" Unrecognized options \n ------------------- \n  Unrecognized options: --bogus, 3 \n  ---------\n"
                 "  For full helptext, run splat-train --help\n")
    assert tyro_error_line(ascii_box, "splat-train") == "unrecognized arguments: --bogus 3; see splat-train --help"
    assert tyro_error_line("", "splat-x") == "invalid arguments; see splat-x --help"


@pytest.mark.bad_input("huge counts (`--model.feat-dim 1000000000`, 10^18 in any int field)", "exit 2, one line naming the field and its bound; what RAM cannot hold is refused by the memory plan before any allocation")
def test_max_steps_bounds_steps_and_checkpoints():
    with pytest.raises(ValidationError, match="steps"):
        apply_overrides(DEFAULTS["3dgs"], {"steps": MAX_STEPS + 1})
    assert apply_overrides(DEFAULTS["3dgs"], {"steps": MAX_STEPS}).steps == MAX_STEPS


@pytest.mark.bad_input("huge counts (`--model.feat-dim 1000000000`, 10^18 in any int field)", "exit 2, one line naming the field and its bound; what RAM cannot hold is refused by the memory plan before any allocation")
def test_the_memory_plan_counts_what_an_anchor_costs(monkeypatch, tmp_path):
    """Counts at their bounds reach the memory plan, which counts each anchor's neural Gaussians and feature:
    scaffold-gs with n_offsets 256 and feat_dim 1024 is refused before any allocation on a 16 GiB machine,
    where its defaults (and 3dgs with as many points) fit."""
    import splat_framework.pipeline.memory_plan as plan
    from splat_framework.data import load_scene
    from splat_framework.data.synthetic import ensure_scene

    scene = load_scene(ensure_scene("forward-tiny"), views=3)
    monkeypatch.setattr(plan, "physical_memory_bytes", lambda: 16 * 2**30)
    monkeypatch.setattr(plan, "available_memory_bytes", lambda: None)
    points = {"init": {"num_points": 100_000}}
    for method in ("3dgs", "scaffold-gs"):
        plan.plan_memory(scene, apply_overrides(DEFAULTS[method], {"model": points}), None)
    huge = apply_overrides(DEFAULTS["scaffold-gs"], {"model": {**points, "n_offsets": 256, "feat_dim": 1024}})
    with pytest.raises(DataError, match="needs about .* of memory"):
        plan.plan_memory(scene, huge, None)
