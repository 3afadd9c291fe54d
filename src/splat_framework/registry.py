"""Method registry: built-ins and plugins register the same way.

A package declares methods in the entry-point group ``splat_framework.methods``;
each entry point names a :class:`MethodSpec`. Without a package, a module named in
``$SPLAT_PLUGINS`` declares the same entries in its ``ENTRY_POINTS`` table
(:mod:`splat_framework.entry_points`: one path for every kind of part); they register after the
installed ones, which register after the framework's own. An entry that does not import, is not a
MethodSpec or whose spec's name is not its entry's is left out with one warning naming it. Named
config variants (the paper's rows) are TOML files::

    # configs/scgaussian-hybrid.toml
    base = "scgaussian"
    description = "Paper, ablation table, row 'hybrid representation': ..."
    [overrides.model]
    lambda_rg = 0.0

The project's own variants live in the top-level ``configs/`` folder, installed as
the package ``splat_configs``; any package lists the packages holding its variants
in the entry-point group ``splat_framework.configs`` (``splat = "splat_configs"``
here; a plugin ships its own the same way), so they are found from a checkout, an
editable install or a wheel alike.

Registration order: the entry-point packages (the framework's ``splat_configs`` first, then in
the order ``importlib.metadata`` lists them), then the folders of ``$SPLAT_CONFIG_PATH``
(os.pathsep-separated), in order. Every kind of part follows one rule
(:class:`~splat_framework.entry_points.Parts`): a variant is named by its file, and a name taken by
a method or by an earlier file keeps what it means; the later file is refused with one warning
naming both. A variant shapes the experiment only: a run option in its overrides (``output``,
``overwrite``, ``viewer_host``, ...), an unknown top-level key or table, is refused naming it. A
variant keeps its own name, so runs of different variants never share an output folder.

Importing this module and listing methods never imports torch.
"""

from __future__ import annotations

import importlib.resources
import os
import stat
import sys
import tomllib
import warnings
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Callable

from .entry_points import CONFIG_ENTRY_POINT_GROUP, Parts, RegistrationWarning, registered
from .entry_points import METHOD_ENTRY_POINT_GROUP as ENTRY_POINT_GROUP


@dataclass(frozen=True)
class MethodSpec:
    """What the framework needs to know about a method.

    Attributes:
        name: the subcommand name, e.g. "3dgs".
        description: one line shown by ``splat-train --help``.
        config_factory: returns the method's default config (a TrainConfig subclass).
            Must not import torch.
        model: "module:Class" of the model (imported only when training starts).
        overrides: nested overrides applied on top of config_factory() (variants).
        base: for a config variant, the registered method it is a variant of (at the root of its
            ``base`` chain); "" for a method.
        pipeline: "module:Class" of the method's :class:`~splat_framework.pipeline.Pipeline`
            (what a step feeds the model, the evaluation): the framework's own, or a subclass.
        source: who registered it (``package my-plugin (my_plugin:spec)``), set by the registry;
            messages about its parts name it.

    ``model`` and ``pipeline`` are :class:`~splat_framework.entry_points.Ref` strings, checked with
    the run's other parts by :func:`splat_framework.engine.parts.resolve_parts` before any data loads.
    """

    name: str
    description: str
    config_factory: Callable[[], Any]
    model: str
    overrides: dict = field(default_factory=dict)
    pipeline: str = "splat_framework.pipeline:Pipeline"
    base: str = ""
    source: str = field(default="", compare=False)

    def default_config(self):
        from .config import apply_overrides

        cfg = self.config_factory()
        if self.overrides:
            cfg = apply_overrides(cfg, self.overrides)
        return cfg.model_copy(update={"method": self.name})

    def model_class(self) -> type:
        """The :class:`~splat_framework.model.gaussians.GaussianModel` subclass ``model`` names
        (a one-line PluginError when it is not one)."""
        return self.ref("model").load()

    def pipeline_class(self) -> type:
        """The :class:`~splat_framework.pipeline.Pipeline` subclass ``pipeline`` names (a one-line
        PluginError when it is not one)."""
        return self.ref("pipeline").load()

    def ref(self, entry: str):
        """The :class:`~splat_framework.entry_points.Ref` of field ``entry`` (``model`` or ``pipeline``)."""
        from .entry_points import MODEL_BASE, PIPELINE_BASE, Ref

        base = {"model": MODEL_BASE, "pipeline": PIPELINE_BASE}[entry]
        return Ref(getattr(self, entry), base, f"method '{self.name}': {entry}", self.source)


def default_config_dirs() -> list[Path]:
    """Folders searched for TOML variants, in the order they register: the packages named in the
    ``splat_framework.configs`` entry points (package data; the framework's own first), then the
    folders of ``$SPLAT_CONFIG_PATH``, each once."""
    dirs = []
    for ep in registered(CONFIG_ENTRY_POINT_GROUP):
        try:
            folder = Path(str(importlib.resources.files(ep.value)))
        except (ImportError, TypeError, ValueError) as e:  # a broken plugin must not kill the CLI
            warnings.warn(f"config variants '{ep.name}' of {ep} cannot be located: {e}", stacklevel=2)
            continue
        if folder.is_dir() and folder not in dirs:
            dirs.append(folder)
    env = os.environ.get("SPLAT_CONFIG_PATH")
    if env:
        dirs += [d for d in (Path(p) for p in env.split(os.pathsep) if p) if d not in dirs]
    return dirs


def _load_methods() -> Parts[MethodSpec]:
    """The methods of the entry points (:class:`~splat_framework.entry_points.Parts`' rule: the
    framework's first, a taken name keeps its first registration)."""

    def check(name: str, spec: object) -> str | None:
        if not isinstance(spec, MethodSpec):
            return f"not a MethodSpec (a {type(spec).__name__})"
        return None if spec.name == name else f"its name is {spec.name!r}, not its entry-point name '{name}'"

    methods = Parts("method").load(ENTRY_POINT_GROUP, check)
    methods.parts = {name: replace(spec, source=methods.sources[name]) for name, spec in methods.parts.items()}
    return methods


VARIANT_KEYS = ("base", "description", "overrides")
"""The top-level keys of a TOML variant."""


def _load_variants(methods: Parts[MethodSpec], dirs: list[Path]) -> dict[str, MethodSpec]:
    """The variants of the ``*.toml`` files in ``dirs`` (in order), each under the name of its file:
    a name taken by a method or an earlier file, or that is not a name, is refused (one warning naming
    both), and so is a file that is not a variant (:func:`_variant_problem`); the others resolve
    their ``base`` chains."""
    from .config import deep_merge

    variants: dict[str, MethodSpec] = {}
    pending: dict[str, Path] = {}
    _BROKEN.clear()
    _BROKEN.update(methods.refused)
    names: Parts[Path] = Parts("config variant", VariantWarning)
    names.sources.update(methods.sources)
    for d in dirs:  # the first registration of a name keeps it
        for f in sorted(_toml_files(d)):
            if names.add(f.stem, f, str(f)):
                pending[f.stem] = f
    _BROKEN.update(names.refused)
    docs: dict[str, dict] = {}
    classes: dict[Callable, type] = {}
    resolved: dict[str, MethodSpec] = dict(methods.parts)
    progress = True
    while pending and progress:  # variants may build on other variants
        progress = False
        for name, f in list(pending.items()):
            if name not in docs:
                doc = _read_variant(f)
                problem = doc if isinstance(doc, str) else _variant_problem(doc)
                if problem:
                    _skip(name, f"{f}: {problem}")
                    del pending[name]
                    continue
                docs[name] = doc
            doc = docs[name]
            parent = doc["base"]
            if parent not in resolved:
                if parent in pending:
                    continue
                _skip(name, f"{f}: {_missing_base(parent, resolved)}")
                del pending[name]
                continue
            p = resolved[parent]
            if p.config_factory not in classes:  # one config built per base method, not per variant
                classes[p.config_factory] = type(p.config_factory())
            problem = _run_option_problem(doc.get("overrides", {}), classes[p.config_factory])
            if problem:
                _skip(name, f"{f}: {problem}")
                del pending[name]
                continue
            spec = MethodSpec(
                name=name,
                description=str(doc.get("description", f"{parent} variant")),
                config_factory=p.config_factory,
                model=p.model,
                overrides=deep_merge(p.overrides, doc.get("overrides", {})),
                pipeline=p.pipeline,
                base=p.base or parent,
                source=p.source,
            )
            del pending[name]
            problem = _invalid_config(spec)
            if problem:
                _skip(name, f"{f}: config variant '{name}' is invalid: {problem}")
                continue
            resolved[name] = variants[name] = spec
            progress = True
    for name, f in pending.items():
        _skip(name, f"{f}: variant '{name}' has a circular base ({_cycle(name, docs)})")
    return variants


def _variant_problem(doc: dict) -> str | None:
    """Why the parsed TOML ``doc`` is not a variant, in one phrase naming the key, or None: a variant
    holds ``base = "METHOD"``, a ``description`` and an ``[overrides]`` table, nothing else."""
    from .errors import did_you_mean

    for key in doc:
        if key not in VARIANT_KEYS:
            return f"unknown key '{key}'{did_you_mean(key, VARIANT_KEYS)}; a variant holds {', '.join(VARIANT_KEYS)}"
    if not isinstance(doc.get("base"), str) or not isinstance(doc.get("overrides", {}), dict):
        return "a variant needs base = \"METHOD\" and an [overrides] table"
    return None


def _run_option_problem(overrides: dict, config_cls: type) -> str | None:
    """One phrase naming the first run option that ``overrides`` sets, or None: a variant sets the
    experiment, never where or how a run goes (the output folder, overwriting, resuming, the viewer
    and its address, the device, ...); those come only from the command line. The run options are
    :func:`~splat_framework.config.run_options` of the base's config class ``config_cls``, the list
    ``--load-config`` follows too."""
    from .config import flag_name, run_options

    taken = [k for k in overrides if k in run_options(config_cls)]
    if not taken:
        return None
    return (f"overrides.{taken[0]} is a run option: a variant sets the experiment, never where or how a run goes "
            f"(give {flag_name(taken[0])} on the command line)")


def _missing_base(parent: str, resolved: dict) -> str:
    """Why ``parent`` is no base: skipped (its own reason's file named) or not registered."""
    from .errors import did_you_mean

    if parent in _BROKEN:
        return f"base '{parent}' is left out ({_BROKEN[parent]})"
    return f"base method '{parent}' is not registered{did_you_mean(parent, resolved)}"


MAX_VARIANT_BYTES = 1 << 20
"""Largest TOML variant read (a variant is a few lines; anything bigger is not one)."""


def _toml_files(folder: Path) -> list[Path]:
    """The ``*.toml`` entries of ``folder`` ([] for a folder that cannot be listed, with one warning line)."""
    try:
        return list(Path(folder).glob("*.toml"))
    except OSError as e:
        warnings.warn(f"{folder}: cannot list config variants ({e.strerror or e}); ignored", VariantWarning, stacklevel=3)
        return []


def _read_variant(f: Path) -> dict | str:
    """The parsed TOML of variant file ``f``, or a one-line reason why it is unusable: not a regular
    file (a FIFO, device or folder is never opened; a symlink counts as what it points at),
    unreadable, too big, not UTF-8 text, or a TOML syntax error."""
    try:
        if not stat.S_ISREG(f.stat().st_mode):
            return "not a regular file"
        fd = os.open(f, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0))  # never blocks, even if swapped for a FIFO
        with os.fdopen(fd, "rb") as fh:
            if not stat.S_ISREG(os.fstat(fh.fileno()).st_mode):
                return "not a regular file"
            raw = fh.read(MAX_VARIANT_BYTES + 1)
    except OSError as e:
        return f"unreadable config variant ({e.strerror or e})"
    if len(raw) > MAX_VARIANT_BYTES:
        return f"not a config variant (larger than {MAX_VARIANT_BYTES} bytes)"
    try:
        return tomllib.loads(raw.decode("utf-8-sig"))
    except UnicodeDecodeError as e:
        return f"not UTF-8 text (byte {e.start}); save it as UTF-8"
    except tomllib.TOMLDecodeError as e:
        return f"TOML syntax error: {_first_line(str(e))}"
    except (ValueError, RecursionError) as e:  # e.g. absurd nesting
        return f"not a TOML file ({_first_line(str(e)) or type(e).__name__})"


def _first_line(text: str) -> str:
    return (text.strip().splitlines() or [""])[0]


def _cycle(name: str, docs: dict[str, dict]) -> str:
    """``a -> b -> a``: the chain of bases from variant ``name`` until a name repeats (or leaves ``docs``)."""
    chain = [name]
    while True:
        parent = docs.get(chain[-1], {}).get("base")
        if not isinstance(parent, str):
            break
        chain.append(parent)
        if parent in chain[:-1] or parent not in docs:
            break
    return " -> ".join(chain)


def _skip(name: str, reason: str) -> None:
    """Record why variant ``name`` is skipped (see :func:`invalid_variant`) and warn in one line."""
    _BROKEN.setdefault(name, reason)
    warnings.warn(f"{reason}; ignored", VariantWarning, stacklevel=3)


class VariantWarning(RegistrationWarning):
    """A config variant was skipped (its name taken or not a name, unreadable, not a regular file, not
    UTF-8 TOML, not a variant, invalid, or its base does not resolve): always one line naming the file."""


#: name -> one-line reason naming the file or the plugin, for every method or variant left out
_BROKEN: dict[str, str] = {}


def _invalid_config(spec: MethodSpec) -> str | None:
    """One line naming the fields of ``spec``'s config that fail validation, or None."""
    from pydantic import ValidationError

    try:
        spec.default_config()
    except ValidationError as e:
        return "; ".join(
            f"{'.'.join(str(x) for x in err['loc']) or 'config'}: {err['msg']}" for err in e.errors()
        )
    except (TypeError, ValueError) as e:  # e.g. an overrides table that is not a table
        return str(e).splitlines()[0] if str(e) else type(e).__name__
    return None


def discover_methods(config_dirs: list[Path] | None = None) -> dict[str, MethodSpec]:
    """All registered methods and config variants, by name: the entry points (the framework's own
    first, then installed packages', then those the modules of ``$SPLAT_PLUGINS`` declare:
    :func:`splat_framework.entry_points.registered`), then the variants of ``config_dirs`` (default:
    :func:`default_config_dirs`). A name keeps its first registration; see :func:`left_out`."""
    methods = _load_methods()
    dirs = default_config_dirs() if config_dirs is None else config_dirs
    return {**methods.parts, **_load_variants(methods, dirs)}


def registered_defaults(config):
    """The config ``config.method`` trains with when nothing is set: its registered defaults (a
    variant's overrides included) at ``config``'s total steps, its schedule rescaled alike; None
    when the name is not registered. What the user set is what ``config`` holds differently."""
    from .config import resolve_steps

    spec = discover_methods().get(config.method)
    if spec is None:
        return None
    defaults = spec.default_config()
    return resolve_steps(defaults.model_copy(update={"steps": config.total_steps, "views": config.views}))


def left_out(name: str) -> str | None:
    """Why the method or variant ``name`` was left out by the last discovery (one line naming its
    file or plugin: a variant that is invalid, a plugin's method that failed to import), or None."""
    return _BROKEN.get(name)


def get_method(name: str) -> MethodSpec:
    """The method or variant ``name``; one left out (:func:`left_out`) raises DataError naming its file or plugin."""
    methods = discover_methods()
    if name not in methods and left_out(name):
        from .errors import DataError

        raise DataError(left_out(name))
    if name not in methods:
        known = ", ".join(sorted(methods))
        raise KeyError(f"unknown method '{name}' (registered: {known})")
    return methods[name]


if __name__ == "__main__":  # pragma: no cover
    for n, s in discover_methods().items():
        print(f"{n:28s} {s.description}", file=sys.stdout)
