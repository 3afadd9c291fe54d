"""The machinery under every config: :class:`SplatConfig` (strict, documented, finite), the
annotation markers code reads (:data:`Steps`, :data:`RUN_OPTION`, ...), the bounded field types
and the command-line validation context (:func:`cli_parsing`).

Torch-free and importing nothing of the project but the part names' pattern, so that every module holding a config (the
run's, the matcher's, the initialisations') can build on it without an import circle;
``splat_framework.config`` re-exports all of it.
"""

from __future__ import annotations

import typing
from contextlib import contextmanager
from contextvars import ContextVar
from typing import Annotated, Any, ContextManager, Iterator, Literal, TypeVar

import tyro
from pydantic import BaseModel, ConfigDict, Field, ValidationError

from ..entry_points import PART_NAME


class Marker:
    """An annotation marker (``Annotated[int, STEPS_MARKER]``): a fact about a field that code reads."""

    def __init__(self, name: str, doc: str) -> None:
        self.name, self.__doc__ = name, doc

    def __repr__(self) -> str:  # pragma: no cover - cosmetic
        return self.name


STEPS_MARKER = Marker("Steps", "This int field counts optimisation iterations (``--steps`` rescales it).")
RUN_OPTION = Marker(
    "RunOption",
    "This field says how a run is carried out, not what is trained: run options (output folder, "
    "device, progress bar, resume, ...) may differ between a run and its ``--resume``; every other "
    "field is the experiment and must not (see :func:`experiment_fields`).",
)
FOLDED = Marker(
    "Folded",
    "This flag is left off its command's main ``--help`` screen, which counts it in its group's line "
    "instead; ``--help GROUP`` shows it (``--help options`` a top-level flag's group). The groups other "
    "than the model and its start are folded whole (see :mod:`splat_framework.cli.help_screen`).",
)
PER_STEP_MARKER = Marker(
    "PerStep",
    "This float field is a factor applied at every iteration (a decay): a schedule rescaled by f takes "
    "it to the power 1/f, so that what it does over the whole run is unchanged (see :func:`scale_schedule`).",
)
SHORTEN_ONLY = Marker(
    "ShortenOnly",
    "This Steps field (a start after a warm-up, a period after which something steps up) follows a "
    "shorter run in proportion and keeps its value in a longer one (see :func:`scale_schedule`).",
)
MAX_STEPS = 10_000_000
"""Most optimisation iterations a run may have (``--steps``; a checkpoint's step is checked against it)."""
MAX_SCHEDULE = 1_000_000_000
"""Most a schedule field (:data:`Steps`) may hold: a schedule is written for the method's own length and
rescaled by ``--steps`` (up to :data:`MAX_STEPS`), so its fields may grow past the total."""
MAX_GAUSSIANS = 50_000_000
"""Most initial Gaussians or points a config may ask for (about 100 GiB at memory_plan.BYTES_PER_GAUSSIAN;
the memory plan then checks the run against the machine's RAM before any work)."""
MAX_MATCHES = 10_000_000
"""Most matches a matching count may name (per pair or in total)."""
MAX_VIEWS = 100_000
"""Most views a view count may name."""
Steps = Annotated[int, STEPS_MARKER, Field(ge=0, le=MAX_SCHEDULE)]
"""An iteration count (>= 0) that ``--steps`` rescales with the schedule."""
StartSteps = Annotated[int, STEPS_MARKER, SHORTEN_ONLY, Field(ge=0, le=MAX_SCHEDULE)]
"""The iteration at which something starts once a warm-up is done (>= 0): a schedule compressed
to fewer iterations compresses it, a longer one keeps it (the warm-up does not need to grow)."""
Period = Annotated[int, STEPS_MARKER, Field(ge=1, le=MAX_SCHEDULE)]
"""An interval in iterations (>= 1: it divides the step number) that ``--steps`` rescales."""
OptionalPeriod = Annotated[Annotated[int, Field(ge=1, le=MAX_SCHEDULE)] | None, STEPS_MARKER]
"""A :data:`Period`, or None for never."""
RampPeriod = Annotated[int, STEPS_MARKER, SHORTEN_ONLY, Field(ge=1, le=MAX_SCHEDULE)]
"""An interval (>= 1) after which something steps up once more (the SH degree): as a start, a
compressed schedule compresses it and a longer one keeps it."""
StepFactor = Annotated[float, PER_STEP_MARKER, Field(gt=0, le=1, allow_inf_nan=False)]
"""A factor in (0, 1] applied at every iteration (1 = off), written for the method's own schedule:
a run f times as long applies its f-th root each step (``--steps``, or more views than the schedule
is written for), so that the product over the run stays the same."""
Interval = Annotated[int, Field(ge=1, le=MAX_SCHEDULE)]
"""An interval in iterations (>= 1) that ``--steps`` does not rescale."""
DEVICE_MARKER = Marker(
    "Device",
    "This str field names a torch device: before it is used, splat_framework.devices.resolve_config_devices "
    "checks it with the resolver of ``--device``, naming the field.",
)
Device = Annotated[str, DEVICE_MARKER, Field(pattern=r"^[a-z_]+(:[0-9]+)?$", max_length=32)]
"""A torch device name (cpu, cuda, cuda:N, mps, ...): its spelling is checked when the config is
built (torch-free), its availability by the resolver of ``--device`` before a run starts."""
LearningRate = Annotated[float, Field(gt=0, le=1, allow_inf_nan=False)]
"""An Adam learning rate, in (0, 1]."""
Fraction = Annotated[float, Field(ge=0, le=1, allow_inf_nan=False)]
"""A number in [0, 1]."""
Positive = Annotated[float, Field(gt=0, allow_inf_nan=False)]
"""A finite number > 0."""
NonNegative = Annotated[float, Field(ge=0, allow_inf_nan=False)]
"""A finite number >= 0."""
Finite = Annotated[float, Field(allow_inf_nan=False)]
"""A finite number (no inf, no nan). Every float field of a :class:`SplatConfig` is finite anyway
(its ``allow_inf_nan=False``); this is for argument classes that are not configs."""


_CLI_PARSING: ContextVar[bool] = ContextVar("splat_cli_parsing", default=False)


class InvalidArguments(Exception):
    """A config built from command-line arguments failed validation (see :func:`cli_parsing`).

    Deliberately not a ValueError: the argument parser (tyro) catches ValueErrors
    raised while it builds nested configs and prints its own multi-line box; this
    passes through to ``cli.common.run_cli``, which prints one line."""

    def __init__(self, error: ValidationError, config_cls: type) -> None:
        super().__init__(str(error))
        self.error, self.config_cls = error, config_cls


@contextmanager
def _switched_on(switch: ContextVar[bool]) -> Iterator[None]:
    """``switch`` True inside the block (this context's), as it was after."""
    token = switch.set(True)
    try:
        yield
    finally:
        switch.reset(token)


def cli_parsing() -> ContextManager[None]:
    """While active (around the argument parser only), a config constructed or validated with
    invalid values raises :class:`InvalidArguments`."""
    return _switched_on(_CLI_PARSING)


def flag_name(field: str) -> str:
    """The command-line flag of a dotted config field, as the user types it:
    ``strategy.grow_grad2d`` -> ``--strategy.grow-grad2d``."""
    return "--" + field.replace("_", "-")


class SplatConfig(BaseModel):
    """Base for every config: strict (unknown fields are errors), documented fields, and every
    float finite (``inf``/``nan`` are refused, naming the field, for every subclass's fields:
    a weight of ``inf`` would skip every step, a threshold of ``inf`` reach OpenCV).

    Every int field has an upper bound (``Field(le=...)``, one of the ``MAX_*`` constants
    above or a bound its docstring states): tests/framework/test_edge_validation.py walks
    every config and checks both rules."""

    model_config = ConfigDict(
        use_attribute_docstrings=True, extra="forbid", validate_assignment=True, allow_inf_nan=False
    )

    def __init__(self, /, **data: Any) -> None:
        try:
            super().__init__(**data)
        except ValidationError as e:
            if _CLI_PARSING.get():
                raise InvalidArguments(e, type(self)) from None
            raise


KIND_FLAG = tyro.conf.arg(
    metavar="KIND",
    help="The group's kind; each kind has its own flags (give the kind before --help to see them).",
)
"""How every ``--PATH.kind`` flag shows: a placeholder and one help text (the field takes any kind its
group accepts, each with its own flags; see :mod:`splat_framework.cli.kinds`)."""

_T = TypeVar("_T")
Kind = Annotated[_T, KIND_FLAG]
"""The one way a kind-tagged config declares its tag: ``kind: Kind[Literal["mcmc"]] = "mcmc"`` (a
one-value Literal, its default the same tag). :class:`KindConfig` checks every subclass for it."""

KIND_TAG = PART_NAME
"""A kind tag: lower-case words joined by hyphens (``ray-gaussian``), as every part is named."""


_DERIVED_VIEW: ContextVar[bool] = ContextVar("derived_view", default=False)


def derived_views() -> ContextManager[None]:
    """Inside, classes derived from a kind's config (the help screen's views of a config, whose
    ``kind`` flag lists the kinds its field takes) skip :class:`KindConfig`'s check of the tag's
    declaration: they are views of a checked class, never registered."""
    return _switched_on(_DERIVED_VIEW)


class KindConfig(SplatConfig):
    """Base of a family of configs tagged by ``kind`` (the init kinds, the strategies): a member of a
    discriminated union, picked by its tag in a saved config, a TOML variant or ``--PATH.kind``.

    A subclass that tags a kind declares it as ``kind: Kind[Literal["TAG"]] = "TAG"`` with a
    :data:`KIND_TAG`; any other declaration is a TypeError naming the class when it is defined. A
    subclass that keeps ``kind: str`` is a base of kinds, tagging none."""

    kind: str
    """The kind's tag."""

    @classmethod
    def __pydantic_init_subclass__(cls, **kwargs: Any) -> None:
        super().__pydantic_init_subclass__(**kwargs)
        field = cls.model_fields["kind"]
        if field.annotation is str or _DERIVED_VIEW.get():
            return
        tags = typing.get_args(field.annotation) if typing.get_origin(field.annotation) is Literal else ()
        if not (len(tags) == 1 and field.default == tags[0] and isinstance(tags[0], str)
                and KIND_TAG.fullmatch(tags[0]) and any(m is KIND_FLAG for m in field.metadata)):
            raise TypeError(
                f"{cls.__module__}.{cls.__qualname__}.kind: declare the tag as kind: Kind[Literal[\"TAG\"]] = \"TAG\" "
                "(splat_framework.plugin.Kind; TAG lower-case words joined by hyphens)"
            )


def registered_kinds(group: str, what: str, base: type, builtins: dict[str, type]) -> dict[str, type]:
    """{kind: config class} of a kind-tagged config family: ``builtins``, then the classes named in
    the entry-point ``group`` (``KIND = "module:ConfigClass"``), under the one rule of every kind
    (:class:`~splat_framework.entry_points.Parts`: a taken kind keeps its first registration). An
    entry that is not a subclass of ``base``, or whose ``kind`` tag is not its entry-point name, is
    left out with one warning naming it (a broken plugin must not kill the CLI)."""
    from ..entry_points import Parts

    def check(name: str, cls: object) -> str | None:
        if not (isinstance(cls, type) and issubclass(cls, base)):
            return f"not a {base.__name__} subclass"
        tag = cls.model_fields["kind"].default
        return None if tag == name else f"its kind tag is {tag!r}, not its entry-point name '{name}'"

    kinds: Parts[type] = Parts(what)
    for name, cls in builtins.items():
        kinds.add(name, cls, f"the framework ({cls.__module__}:{cls.__qualname__})")
    return kinds.load(group, check).parts


def as_registered_kind(value: Any, kinds: dict[str, type], default_kind: str, what: str) -> Any:
    """``value`` (a dict, e.g. from config.json, or a config) as the config class of its ``kind``
    among ``kinds`` (a missing kind in a dict: ``default_kind``); an unknown kind is a ValueError
    naming the registered ones."""
    kind = value.get("kind", default_kind) if isinstance(value, dict) else getattr(value, "kind", None)
    if not isinstance(kind, str) or kind not in kinds:
        raise ValueError(f"unknown {what} kind {kind!r} (registered: {', '.join(repr(k) for k in kinds)})")
    cls = kinds[kind]
    return value if type(value) is cls else cls.model_validate(value if isinstance(value, dict) else value.model_dump())
