"""Crafted and fuzzed files: every PLY, TOML variant, config.json and checkpoint ends in a result or a
one-line DataError / CheckpointError naming the file, never another exception (issue 17, item 11 and
the fuzz harness)."""

from __future__ import annotations

import hashlib
import io
import tempfile
import warnings
from pathlib import Path

import pytest
import torch
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from splat_framework import registry
from splat_framework.config import read_config_json, save_config
from splat_framework.engine.checkpoint import MAGIC, check_structure, load_checkpoint, save_checkpoint
from splat_framework.errors import CheckpointError, DataError
from splat_framework.export.ply import load_ply, write_ply

FUZZ = settings(max_examples=120, deadline=None, suppress_health_check=[HealthCheck.too_slow])


def _gaussians(n=5, k1=3):
    g = torch.Generator().manual_seed(n)
    return {
        "means": torch.randn(n, 3, generator=g), "quats": torch.randn(n, 4, generator=g),
        "scales": torch.randn(n, 3, generator=g), "opacities": torch.randn(n, generator=g),
        "sh0": torch.randn(n, 1, 3, generator=g), "shN": torch.randn(n, k1, 3, generator=g),
    }


def _valid_ply() -> bytes:
    with tempfile.TemporaryDirectory() as d:
        return write_ply(Path(d) / "g.ply", _gaussians()).read_bytes()


VALID_PLY = _valid_ply()
HEADER, BODY = VALID_PLY.split(b"end_header\n", 1)


def _one_line_error(fn, *kinds):
    """Call ``fn``; it returns, or raises one of ``kinds`` with a one-line message. Returns the message or None."""
    try:
        fn()
    except kinds as e:
        msg = str(e)
        assert msg and "\n" not in msg, msg
        return msg
    return None


# ------------------------------------------------------------------ PLY, crafted
def _with_header(lines: list[str], body: bytes = BODY) -> bytes:
    return ("\n".join(lines) + "\n").encode() + body


def _header_lines() -> list[str]:
    return HEADER.decode().splitlines() + ["end_header"]


def _replace(lines, prefix, new):
    return [new if ln.startswith(prefix) else ln for ln in lines]


CRAFTED = {
    "truncated body": VALID_PLY[:-7],
    "vertex count larger than the file": _with_header(_replace(_header_lines(), "element vertex", "element vertex 99999999999")),
    "vertex count beyond int64": _with_header(_replace(_header_lines(), "element vertex", "element vertex 1" + "0" * 30)),
    "negative vertex count": _with_header(_replace(_header_lines(), "element vertex", "element vertex -3")),
    "vertex count not a number": _with_header(_replace(_header_lines(), "element vertex", "element vertex many")),
    "element without a count": _with_header(_replace(_header_lines(), "element vertex", "element vertex")),
    "unknown property type": _with_header(_replace(_header_lines(), "property float x", "property float128 x")),
    "property without a name": _with_header(_replace(_header_lines(), "property float x", "property float")),
    "duplicate property": _with_header(_replace(_header_lines(), "property float y", "property float x")),
    "f_rest with a bad suffix": _with_header(_replace(_header_lines(), "property float f_rest_0", "property float f_rest_zero")),
    "format without a value": _with_header(_replace(_header_lines(), "format", "format")),
    "ascii format": _with_header(_replace(_header_lines(), "format", "format ascii 1.0")),
    "no end_header": HEADER + b"\n",
    "empty": b"",
    "not a ply": b"solid cube\n",
}


@pytest.mark.parametrize("case", sorted(CRAFTED))
@pytest.mark.bad_input("crafted or fuzzed PLY files, TOML variants, config.json, checkpoints", "a result or one-line `DataError`/`CheckpointError`, never another exception")
def test_crafted_ply_files_give_one_line_errors(tmp_path, case):
    path = tmp_path / "bad.ply"
    path.write_bytes(CRAFTED[case])
    msg = _one_line_error(lambda: load_ply(path), DataError)
    assert msg is not None and str(path) in msg, (case, msg)


# ------------------------------------------------------------------ PLY, fuzzed
@FUZZ
@given(st.data())
@pytest.mark.bad_input("crafted or fuzzed PLY files, TOML variants, config.json, checkpoints", "a result or one-line `DataError`/`CheckpointError`, never another exception")
def test_fuzzed_ply_files_load_or_raise_data_error(data):
    kind = data.draw(st.sampled_from(["bytes", "cut", "flip", "header line"]))
    if kind == "bytes":
        blob = data.draw(st.binary(max_size=400))
        if data.draw(st.booleans()):
            blob = b"ply\n" + blob
    elif kind == "cut":
        blob = VALID_PLY[: data.draw(st.integers(0, len(VALID_PLY)))]
    elif kind == "flip":
        blob = bytearray(VALID_PLY)
        for _ in range(data.draw(st.integers(1, 8))):
            i = data.draw(st.integers(0, len(HEADER) + 20))
            blob[i] = data.draw(st.integers(0, 255))
        blob = bytes(blob)
    else:
        lines = _header_lines()
        i = data.draw(st.integers(1, len(lines) - 1))
        words = data.draw(st.lists(st.sampled_from(
            ["element", "vertex", "face", "property", "float", "uchar", "list", "x", "f_rest_1", "-1", "0", "7",
             "99999999999999999999", "format", "binary_big_endian", "end_header", "comment", "\x00"]), max_size=4))
        lines.insert(i, " ".join(words))
        blob = _with_header(lines)
    with tempfile.TemporaryDirectory() as d:
        path = Path(d) / "f.ply"
        path.write_bytes(blob)
        _one_line_error(lambda: load_ply(path), DataError)


# ------------------------------------------------------------------ TOML variants
TOML_PIECES = ['base = "3dgs"', 'base = "nope"', "base = 3", '[overrides]', '[overrides.model]', "steps = 5",
               "steps = -1", 'sh_degree = "three"', "sh_degree = 2", "overrides = 3", "[[overrides]]", "x = [1, 2",
               'description = "d"', "description = 5", "[overrides.strategy]", "refine_every = 0", "= 1", "\x00"]


@FUZZ
@given(st.lists(st.sampled_from(TOML_PIECES), max_size=6))
@pytest.mark.bad_input("crafted or fuzzed PLY files, TOML variants, config.json, checkpoints", "a result or one-line `DataError`/`CheckpointError`, never another exception")
def test_fuzzed_toml_variants_never_break_discovery(pieces):
    with tempfile.TemporaryDirectory() as d:
        (Path(d) / "fuzzed.toml").write_text("\n".join(pieces) + "\n")
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            methods = registry.discover_methods([Path(d)])
        assert "3dgs" in methods and "scgaussian" in methods
        for w in caught:
            assert "\n" not in str(w.message), str(w.message)
        if "fuzzed" in methods:
            methods["fuzzed"].default_config()  # a variant that was accepted builds its config


TOML_TEXT = st.one_of(
    st.text(max_size=200),  # any Unicode, NULs and surrogates' neighbours included
    st.lists(st.sampled_from(TOML_PIECES + ['base = "scgaussian"', "lambda_rg = inf", "lambda_rg = nan",
                                            "feat_dim = 1000000000", 'device = "cuda:x"', "[overrides.model.matching]",
                                            "magsac_threshold = inf", "max_matches = -1"]), max_size=8).map("\n".join),
)
TOML_BYTES = st.one_of(
    st.binary(max_size=300),
    TOML_TEXT.map(lambda t: t.encode("utf-16")),
    TOML_TEXT.map(lambda t: t.encode("utf-8", "surrogatepass")),
)


@FUZZ
@given(st.lists(TOML_BYTES, min_size=1, max_size=3))
@pytest.mark.bad_input("fuzzed config values (overrides and command line) and checkpoint headers", "a usable config or one line naming the field; a header is accepted only when usable")
def test_random_bytes_as_toml_variants_never_break_discovery(blobs):
    """Random bytes, UTF-16 or any text in $SPLAT_CONFIG_PATH: discovery never raises, at most one warning
    line per file, and an accepted variant builds a config whose floats are finite (issue 40)."""
    with tempfile.TemporaryDirectory() as d:
        for i, blob in enumerate(blobs):
            (Path(d) / f"v{i}.toml").write_bytes(blob)
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            methods = registry.discover_methods([Path(d)])
        assert "3dgs" in methods and "scgaussian" in methods
        per_file = [str(w.message).split(":")[0] for w in caught]
        assert all("\n" not in str(w.message) for w in caught), [str(w.message) for w in caught]
        assert len(per_file) == len(set(per_file)) <= len(blobs), per_file
        for i in range(len(blobs)):
            name = f"v{i}"
            assert (name in methods) != (registry.left_out(name) is not None), name
            if name in methods:
                cfg = methods[name].default_config()
                assert "inf" not in cfg.model_dump_json() and "NaN" not in cfg.model_dump_json()


# ------------------------------------------------------------------ config.json
def _valid_config_json() -> bytes:
    cfg = registry.get_method("3dgs").default_config()
    with tempfile.TemporaryDirectory() as d:
        save_config(cfg, Path(d) / "config.json")
        return (Path(d) / "config.json").read_bytes()


VALID_CONFIG = _valid_config_json()


@FUZZ
@given(st.data())
@pytest.mark.bad_input("crafted or fuzzed PLY files, TOML variants, config.json, checkpoints", "a result or one-line `DataError`/`CheckpointError`, never another exception")
def test_fuzzed_config_json_reads_or_raises_data_error(data):
    blob = bytearray(VALID_CONFIG)
    if data.draw(st.booleans()):
        blob = blob[: data.draw(st.integers(0, len(blob)))]
    for _ in range(data.draw(st.integers(0, 4))):
        if blob:
            blob[data.draw(st.integers(0, len(blob) - 1))] = data.draw(st.integers(0, 255))
    trust = data.draw(st.booleans())
    with tempfile.TemporaryDirectory() as d:
        path = Path(d) / "config.json"
        path.write_bytes(bytes(blob))
        _one_line_error(lambda: read_config_json(path, trust_edits=trust), DataError)


# ------------------------------------------------------------------ checkpoints
PAYLOADS = {
    "not a dict": [1, 2],
    "no params": {"step": 1},
    "params not a dict": {"step": 1, "params": [torch.ones(2)]},
    "empty params": {"step": 1, "params": {}},
    "a scalar parameter": {"step": 1, "params": {"x": torch.tensor(1.0)}},
    "int parameter": {"step": 1, "params": {"x": torch.ones(3, dtype=torch.int64)}},
    "rows differ": {"step": 1, "params": {"x": torch.ones(3), "y": torch.ones(4)}},
    "optimizers not a dict": {"step": 1, "params": {"x": torch.ones(3)}, "optimizers": 5},
    "optimizer for nothing": {"step": 1, "params": {"x": torch.ones(3)}, "optimizers": {"z": {"state": {}}}},
    "moments of another shape": {"step": 1, "params": {"x": torch.ones(3)},
                                 "optimizers": {"x": {"state": {0: {"exp_avg": torch.ones(5)}}}}},
}


@pytest.mark.parametrize("case", sorted(PAYLOADS))
def test_checkpoint_payloads_with_a_valid_checksum_are_checked(tmp_path, case):
    buf = io.BytesIO()
    torch.save(PAYLOADS[case], buf)
    data = buf.getvalue()
    path = tmp_path / "step-0000001.ckpt"
    path.write_bytes(MAGIC + hashlib.sha256(data).hexdigest().encode() + b"\n" + data)

    def load_and_check():
        check_structure(path, load_checkpoint(path))

    msg = _one_line_error(load_and_check, CheckpointError)
    assert msg is not None and str(path) in msg, (case, msg)


@FUZZ
@given(st.data())
@pytest.mark.bad_input("crafted or fuzzed PLY files, TOML variants, config.json, checkpoints", "a result or one-line `DataError`/`CheckpointError`, never another exception")
def test_fuzzed_checkpoint_files_load_or_raise_checkpoint_error(data):
    with tempfile.TemporaryDirectory() as d:
        good = save_checkpoint(Path(d), 1, {"step": 1, "params": {"x": torch.ones(3)}})
        blob = bytearray(good.read_bytes())
        if data.draw(st.booleans()):
            blob = blob[: data.draw(st.integers(0, len(blob)))]
        for _ in range(data.draw(st.integers(0, 4))):
            if blob:
                blob[data.draw(st.integers(0, len(blob) - 1))] = data.draw(st.integers(0, 255))
        good.write_bytes(bytes(blob))
        _one_line_error(lambda: check_structure(good, load_checkpoint(good)), CheckpointError)


# ------------------------------------------------------------------ checkpoint headers
TENSORS = st.builds(
    lambda dtype, rows, value: torch.full((rows, 3), value).to(dtype),
    st.sampled_from([torch.float32, torch.float32, torch.float64, torch.float16, torch.int64, torch.bool]),
    st.integers(0, 3),
    st.sampled_from([0.0, 1.5, float("nan"), float("inf"), -1e30]),
)
STEPS = st.one_of(st.integers(-(10**13), 10**13), st.sampled_from([0, 1, 7, -7, 10**12]), st.floats(), st.text(max_size=3),
                  st.none(), st.booleans())


@FUZZ
@given(st.data())
@pytest.mark.bad_input("fuzzed config values (overrides and command line) and checkpoint headers", "a usable config or one line naming the field; a header is accepted only when usable")
def test_fuzzed_checkpoint_headers_are_checked(data):
    """Any step, keys and dtypes under a valid checksum: check_structure accepts only a step in [0, MAX_STEPS]
    equal to the file name's, finite float32 parameters with one row count; else one line naming the file."""
    from splat_framework.config import MAX_STEPS

    step = data.draw(STEPS, label="step")
    name_step = data.draw(st.one_of(st.just(step if isinstance(step, int) and not isinstance(step, bool) and step >= 0 else 5),
                                    st.integers(0, 10**13)), label="name step")
    payload = {"step": step, "params": data.draw(st.dictionaries(st.sampled_from(["means", "x", ""]), TENSORS, max_size=3))}
    for key in data.draw(st.lists(st.sampled_from(["networks", "optimizers", "rng", "junk"]), max_size=2, unique=True)):
        payload[key] = data.draw(st.one_of(st.none(), st.integers(), st.dictionaries(st.text(max_size=3), TENSORS, max_size=2)))
    if data.draw(st.booleans()):
        del payload["step"]
    with tempfile.TemporaryDirectory() as d:
        buf = io.BytesIO()
        torch.save(payload, buf)
        path = Path(d) / f"step-{name_step:07d}.ckpt"
        path.write_bytes(MAGIC + hashlib.sha256(buf.getvalue()).hexdigest().encode() + b"\n" + buf.getvalue())
        msg = _one_line_error(lambda: check_structure(path, load_checkpoint(path)), CheckpointError)
    if msg is None:  # accepted: the header is one training can use
        assert isinstance(payload["step"], int) and 0 <= payload["step"] <= MAX_STEPS and payload["step"] == name_step
        params = payload["params"]
        assert params and all(t.dtype == torch.float32 and torch.isfinite(t).all() for t in params.values())
    else:
        assert str(path) in msg, msg
