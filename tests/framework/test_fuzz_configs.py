"""Fuzzed config values (issue 40, item 5): a random value in any field of any registered method's
config, set through a variant's overrides or typed on splat-train's command line, gives either a
config whose floats are finite and whose counts are bounded, or one line naming the field."""

from __future__ import annotations

import json
import math

import pytest
import tyro
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from pydantic import ValidationError

from config_walk import DEFAULTS, FIELDS, METHODS, nested
from splat_framework.cli.common import ArgumentsError, config_path, format_validation_error, one_line_parse_errors
from splat_framework.cli.train import build_parser_type
from splat_framework.config import MAX_SCHEDULE, InvalidArguments, apply_overrides

FUZZ = settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
VALUES = st.one_of(
    st.integers(-(2**70), 2**70),
    st.sampled_from([0, -1, 1, 2**31, 10**9, 10**18]),
    st.floats(allow_nan=True, allow_infinity=True),
    st.sampled_from([math.inf, -math.inf, math.nan, 1e308, -0.0]),
    st.text(max_size=6),
    st.booleans(),
    st.none(),
    st.lists(st.integers(), max_size=2),
)


def _numbers(tree) -> list:
    if isinstance(tree, dict):
        return [x for v in tree.values() for x in _numbers(v)]
    return [tree] if isinstance(tree, (int, float)) and not isinstance(tree, bool) else []


def _assert_usable(config) -> None:
    """Every float of an accepted config is finite and every count bounded (no inf, nan or 10^18 count)."""
    for x in _numbers(json.loads(config.model_dump_json())):
        assert math.isfinite(x) and (isinstance(x, float) or abs(x) <= max(MAX_SCHEDULE, 2**32)), x


@FUZZ
@given(st.data())
@pytest.mark.bad_input("fuzzed config values (overrides and command line) and checkpoint headers", "a usable config or one line naming the field; a header is accepted only when usable")
def test_fuzzed_override_values_build_a_usable_config_or_name_the_field(data):
    method, path, _ = data.draw(st.sampled_from(FIELDS), label="field")
    value = data.draw(VALUES, label="value")
    try:
        cfg = apply_overrides(DEFAULTS[method], nested(path, value))
    except ValidationError as e:
        line = format_validation_error(e)
        # a strategy's kind tag is checked at the strategy (the discriminated union)
        where = ".".join(path[:-1]) if path[-1] == "kind" else ".".join(path)
        assert "\n" not in line and where in line, (path, line)
        return
    _assert_usable(cfg)


PARSER = build_parser_type(METHODS)
FLAG_FIELDS = [(m, p) for m, p, types in FIELDS if types and p[-1] not in ("method", "kind", "default_steps", "schedule_views")]
CLI_VALUES = st.one_of(
    st.sampled_from(["inf", "-inf", "nan", "NaN", "1e400", "-1", "0", "1e18", "1000000000000000000", "abc", "", "1.5", "True"]),
    st.integers(-(2**66), 2**66).map(str),
    st.floats().map(repr),
    st.text(alphabet=st.characters(blacklist_categories=("Cs",), blacklist_characters="\x00"), max_size=5),
)


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.sampled_from(FLAG_FIELDS), CLI_VALUES)
@pytest.mark.bad_input("fuzzed config values (overrides and command line) and checkpoint headers", "a usable config or one line naming the field; a header is accepted only when usable")
def test_fuzzed_command_line_values_parse_or_give_one_line(field, value):
    """The same through tyro, as splat-train METHOD parses it (the method's config class alone, 2x faster than
    the union of every method): a config, or one line (ArgumentsError for what tyro rejects, InvalidArguments
    naming the dotted field for what pydantic rejects)."""
    method, path = field
    flag = "--" + ".".join(path).replace("_", "-")
    args = [f"{flag}={value}"]
    default = DEFAULTS[method]
    try:
        with one_line_parse_errors("splat-train", METHODS):
            cfg = tyro.cli(type(default), default=default, args=args, prog="splat-train")
    except ArgumentsError as e:
        assert "\n" not in str(e) and str(e), str(e)
        return
    except InvalidArguments as e:
        line = format_validation_error(e.error)
        assert "\n" not in line, line
        return
    except Exception as e:  # a parser-level error that run_cli prints as one line (serving.InvalidAddress)
        assert getattr(type(e), "cli_exit_code", None) == 2, repr(e)
        assert "\n" not in str(e) and str(e), str(e)
        return
    _assert_usable(cfg)


@pytest.mark.parametrize("value", ["inf", "nan", "-inf"])
@pytest.mark.bad_input("`inf` or `nan` in any float of any config (`--model.lambda-rg inf`, matching thresholds)", "exit 2, one line naming the field")
def test_a_non_finite_loss_weight_on_the_command_line_names_the_field(value):
    with pytest.raises(InvalidArguments) as e:
        with one_line_parse_errors("splat-train", METHODS):
            tyro.cli(PARSER, args=["scgaussian", "--model.lambda-rg", value], prog="splat-train")
    line = format_validation_error(e.value.error, config_path(e.value.config_cls))  # as run_cli prints it
    assert line == "model.lambda_rg: Input should be a finite number"


@pytest.mark.parametrize("kind", [[], {}, 3, None])
def test_a_kind_that_is_not_a_name_is_named_as_unknown(kind):
    """Found by the fuzzer: ``{"kind": []}`` raised TypeError (unhashable) from inside the kind switch."""
    for method in ("3dgs", "octree-gs"):
        with pytest.raises(ValueError, match="unknown initialisation kind"):
            apply_overrides(DEFAULTS[method], {"model": {"init": {"kind": kind}}})
