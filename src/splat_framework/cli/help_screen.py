"""``splat-train METHOD --help``, one group a screen (torch-free).

A method has over a hundred flags; its main screen (``--help``) shows the top-level flags, its
model's and its start's (:data:`MAIN_GROUPS`), and of every other group (the matching prior, the
regularisers, the strategy, the learning rates, ...) only its ``kind``: the choice, whose flags
then differ. A flag marked :data:`~splat_framework.config.FOLDED` (a rarely used run option) is
left off too. The screen's description counts what it leaves off by group; ``--help GROUP`` shows
one group in full (``--help options``: every top-level flag), ``--help all`` every flag. Every
``kind`` flag lists the kinds its field accepts (the registered strategies and init kinds).

The screen is tyro's own help of the method's config with the fields it leaves off suppressed:
:func:`help_view` builds that config, used only to print the help (nothing is parsed from it).
"""

from __future__ import annotations

import typing
from typing import Annotated, Any

from pydantic import BaseModel, Field, create_model

from ..config.base import derived_views
from .kinds import suppressed, unannotated, union_kinds

HELP_FLAGS = ("-h", "--help")
TOP = "options"
"""The name of the top-level flags' group (tyro's box title for them)."""
ALL = "all"
"""``--help all``: every flag."""
MAIN_GROUPS = ("", "model", "model.init")
"""The groups whose flags the main screen shows (``""``: the top-level flags); of the others, their kind only."""


def help_group(argv: list[str], method: str | None) -> tuple[list[str], str | None]:
    """(``argv`` without a group named right after ``-h``/``--help``, that group): ``""`` for the main
    screen, None when ``argv`` asks for no help. The word after ``--help`` is a group unless it is a
    flag or the ``method`` itself (``splat-train --help METHOD``)."""
    for i, arg in enumerate(argv):
        if arg in HELP_FLAGS:
            word = argv[i + 1] if i + 1 < len(argv) else None
            if word is None or word.startswith("-") or word == method:
                return argv, ""
            return argv[: i + 1] + argv[i + 2:], word
    return argv, None


def _flag(path: str) -> str:
    return path.replace("_", "-")


def _leaf_groups(config: BaseModel, path: str = "") -> typing.Iterator[tuple[str, str, Any]]:
    """(group path, field name, field info) of every flag of ``config`` (not its ``kind`` tags, nor suppressed fields)."""
    for name, info in type(config).model_fields.items():
        value = config.__dict__.get(name)
        if isinstance(value, BaseModel):
            yield from _leaf_groups(value, f"{path}{name}.")
        elif name != "kind" and not suppressed(info):
            yield path.rstrip("."), name, info


def flag_names(config: BaseModel, argv: list[str] = ()) -> list[str]:
    """Every flag of ``config`` on the command line (``--data``, ``--model.init.kind``,
    ``--model.sh-degree``; with the kinds ``argv`` chooses), the help flags included: the names a
    mistyped flag is matched against (``cli.common.tyro_error_line``)."""
    from .kinds import choose_kinds

    def walk(value: BaseModel, path: str) -> typing.Iterator[str]:
        for name, info in type(value).model_fields.items():
            sub = value.__dict__.get(name)
            if isinstance(sub, BaseModel):
                yield from walk(sub, f"{path}{name}.")
            elif not suppressed(info):
                yield "--" + _flag(path + name)

    return [*HELP_FLAGS, *walk(choose_kinds(config, list(argv)), "")]


def groups(config: BaseModel) -> dict[str, int]:
    """{group (as its flags spell it; :data:`TOP` for the top level): number of flags} of ``config``."""
    out: dict[str, int] = {}
    for group, _, _ in _leaf_groups(config):
        key = _flag(group) or TOP
        out[key] = out.get(key, 0) + 1
    return out


def chosen_kinds(argv: list[str]) -> tuple[str, ...]:
    """The groups whose kind ``argv`` chooses (``--model.matching.kind sift``: ``model.matching``)."""
    flags = (a.partition("=")[0] for a in argv if a.startswith("--"))
    return tuple(_flag(f[2:-len(".kind")]) for f in flags if f.endswith(".kind"))


def _shown_on_main(group: str, info, unfolded: tuple[str, ...] = ()) -> bool:
    from ..config import FOLDED

    opened = group in MAIN_GROUPS or any(_flag(group) == g or _flag(group).startswith(g + ".") for g in unfolded)
    return opened and not any(m is FOLDED for m in info.metadata)


def _shown_in(chosen: str, unfolded: tuple[str, ...]):
    """Whether a flag of ``group`` is shown on the screen of ``chosen`` (a group, :data:`TOP`, :data:`ALL`
    or "" for the main screen, which shows every group's ``kind`` and the groups whose kind the
    command line chooses, ``unfolded``)."""
    def shown(group: str, info, is_kind: bool) -> bool:
        if chosen == ALL or (chosen == "" and is_kind):
            return True
        if chosen == "":
            return _shown_on_main(group, info, unfolded)
        if chosen == TOP:
            return group == ""
        flag = _flag(group)
        return flag == chosen or flag.startswith(chosen + ".")
    return shown


def folded_line(config: BaseModel, command: str, unfolded: tuple[str, ...] = ()) -> str:
    """The main screen's line on what it leaves off: each group's count of flags not shown, and how to see them."""
    left: dict[str, int] = {}
    for group, _, info in _leaf_groups(config):
        if not _shown_on_main(group, info, unfolded):
            key = _flag(group) or TOP
            left[key] = left.get(key, 0) + 1
    if not left:
        return ""
    entries = [f"{g} ({n})," for g, n in left.items()] + [f"every flag: --help {ALL}."]
    entries[-2] = entries[-2].rstrip(",") + ";"
    lines = [""]
    for entry in entries:  # an entry is never split across lines
        lines[-1:] = [f"{lines[-1]} {entry}".strip()] if len(lines[-1]) + len(entry) < 90 else [lines[-1], entry]
    return "\n".join([f"Flags left off this screen, by group ({command} --help GROUP shows one):",
                      *(f"  {line}" for line in lines)])


def help_view(config: BaseModel, chosen: str, command: str, unfolded: tuple[str, ...] = ()) -> tuple[BaseModel, str]:
    """(``config`` as the help screen of ``chosen`` shows it, that screen's extra description).

    ``chosen``: "" for the main screen, a group (``strategy``, ``model.matching``, :data:`TOP`) or
    :data:`ALL`; ``unfolded``: the groups the main screen shows in full besides :data:`MAIN_GROUPS`
    (those whose kind the command line chooses, :func:`chosen_kinds`). The returned config's fields
    that the screen leaves off are suppressed and each ``kind`` lists the kinds its field accepts;
    it only prints help (its classes are derived for it). A group the config does not have is an
    ArgumentsError naming those it has."""
    from .common import ArgumentsError, did_you_mean

    chosen = _flag(chosen)
    known = groups(config)
    if chosen not in ("", ALL) and chosen not in known and not any(g.startswith(chosen + ".") for g in known):
        choices = [TOP, *(g for g in known if g != TOP), ALL]
        raise ArgumentsError(f"--help {chosen}: not a group of {command} (groups: {', '.join(choices)})"
                             f"{did_you_mean(chosen, choices)}")
    view, _ = _view(config, "", _shown_in(chosen, unfolded), {})
    if chosen == "":
        return view, folded_line(config, command, unfolded)
    what = "every flag" if chosen == ALL else f"the flags of {chosen}"
    return view, f"This screen: {what}; {command} --help: the main flags."


def _view(config: BaseModel, path: str, shown, kinds: dict[str, type]) -> tuple[BaseModel, bool]:
    """(``config`` as an instance of a class derived from its own, whose fields ``shown`` rejects are
    suppressed and whose ``kind`` lists ``kinds`` (those its field accepts); whether any field shows)."""
    import tyro

    cls = type(config)
    hints = typing.get_type_hints(cls, include_extras=True)
    group = path.rstrip(".")
    fields: dict[str, Any] = {}
    values: dict[str, Any] = {}
    visible = False
    for name, info in cls.model_fields.items():
        value = config.__dict__.get(name, info)  # a required field left unset (a PLY's path): info stands for it
        if isinstance(value, BaseModel):
            sub, seen = _view(value, f"{path}{name}.", shown, union_kinds(hints[name]))
            keep = tuple(m for m in typing.get_args(hints[name])[1:] if type(m).__module__.startswith("tyro"))
            shape = Annotated[(type(sub), *keep)] if keep else type(sub)
            fields[name] = (shape if seen else tyro.conf.Suppress[shape], Field(description=info.description))
            values[name], visible = sub, visible or seen
            continue
        is_kind = name == "kind" and bool(kinds)
        if not shown(group, info, is_kind) or (name == "kind" and not kinds):
            fields[name] = (tyro.conf.Suppress[hints[name]], Field(description=info.description))
        elif is_kind:  # shown, with the kinds listed (even a kind the parser hides: a strategy's)
            visible = True
            what = " (each with its own flags)" if len(kinds) > 1 else ""
            help_ = f"{(info.description or 'The kind').rstrip('.')}: {', '.join(kinds)}{what}."
            fields[name] = (Annotated[unannotated(hints[name]), tyro.conf.arg(metavar="KIND", help=help_)],
                            Field(description=info.description))
        else:
            visible = visible or not suppressed(info)
        if value is not info:
            values[name] = value
    with derived_views():
        derived = create_model(cls.__name__, __base__=cls, __module__=cls.__module__, __doc__=cls.__doc__, **fields)
    return derived.model_construct(**values), visible


def methods_screen(methods: dict, description: str, columns: int | None = None) -> str:
    """``splat-train --help`` without a method: every registered method with its one line, and under
    each the config variants built on it (``MethodSpec.base``: the paper's rows and others), each a
    METHOD of its own. Plain text, wrapped at ``columns`` (the terminal's width, else 100)."""
    import shutil
    import textwrap

    width = columns or shutil.get_terminal_size((100, 24)).columns
    roots = [name for name, spec in methods.items() if not spec.base or spec.base not in methods]
    variants = {root: sorted(n for n, s in methods.items() if s.base == root and n != root) for root in roots}
    names = [*roots, *(v for vs in variants.values() for v in vs)]
    column = min(max(len(n) for n in names) + 4, 30, width // 2)

    def entry(name: str, indent: int) -> list[str]:
        head = " " * indent + name
        text = methods[name].description
        if len(head) + 2 > column:  # a long name: its line, then the text under the column
            return [head, *textwrap.wrap(text, width, initial_indent=" " * column, subsequent_indent=" " * column)]
        return textwrap.wrap(text, width, initial_indent=head.ljust(column), subsequent_indent=" " * column) or [head]

    lines = ["usage: splat-train METHOD [OPTIONS]  ('splat-train METHOD --help': the method's options)", "",
             *textwrap.wrap(description, width), "",
             "methods, each with its config variants under it (a variant is a METHOD too):"]
    for root in roots:
        lines += entry(root, 2)
        for variant in variants[root]:
            lines += entry(variant, 6)
    return "\n".join(lines) + "\n"
