"""Where a model's initial points come from: the kinds of ``model.init`` (torch-free: read for ``--help``).

Each kind is a config tagged by ``kind`` (a member of a discriminated union, as the strategies
are) that names the function building its points as ``points_fn = "module:function"``;
:func:`splat_framework.model.init.initial_points` calls it, the one place that builds start
points for every method (3dgs's Gaussians, Scaffold-GS's and Octree-GS's anchors, SCGaussian's
ordinary Gaussians). A function takes ``(config, datamanager, generator)`` and returns a
:class:`~splat_framework.model.init.StartPoints` (points [N, 3], colours [N, 3] in [0, 1], and seconds
per named set-up phase).

Every model accepts the built-in kinds (random, frustum, ply; triangulated and sfm are declared
in the framework's own entry points, as a plugin's kinds are) and those a plugin registers in the entry-point group
``splat_framework.inits`` (:data:`InitKinds`; the entry point's name is the kind's tag, declared as
``kind: Kind[Literal["TAG"]] = "TAG"``); a model that accepts fewer lists them with :func:`init_field`.
On the command line ``--model.init.kind K`` picks one and shows its flags (``splat-train 3dgs
--model.init.kind ply --help``), a TOML variant writes ``[overrides.model.init] kind = "K"``.
"""

from __future__ import annotations

from functools import cache
from pathlib import Path
from typing import Annotated, Any, ClassVar, Literal, Union

import tyro
from pydantic import BeforeValidator, Field, SerializeAsAny

from .base import MAX_GAUSSIANS, Kind, KindConfig, Positive, as_registered_kind, registered_kinds
from .matching import AutoMatchConfig, MatchKinds

FALLBACK_POINTS = 10_000
"""Random points a model starts from when its prior (matches, triangulated points) is missing or sparse."""

class InitConfig(KindConfig):
    """Base of the initialisations' configs: a discriminated-union member tagged by ``kind``
    (declared as ``kind: Kind[Literal["TAG"]] = "TAG"``, see :class:`~.base.KindConfig`)."""

    points_fn: ClassVar[str]
    """``module:function`` building this kind's points (see the module docstring; a
    :class:`~splat_framework.entry_points.Ref`, checked before any data loads)."""

    @classmethod
    def registered_kinds(cls) -> dict[str, type["InitConfig"]]:
        """The kinds a field of this base type accepts (:func:`init_kinds`; the command line's
        ``--model.init.kind``, see :mod:`splat_framework.cli.kinds`)."""
        return init_kinds()

    @property
    def planned_points(self) -> int:
        """Points this init is expected to give, for the memory plan before any data is read (0: unknown)."""
        return 0


class RandomInitConfig(InitConfig):
    """Random init (the 3DGS reference's): points uniform in the scene's content box (else the box of the training frusta), grey."""

    kind: Kind[Literal["random"]] = "random"
    """The init's kind."""
    num_points: int = Field(10_000, ge=1, le=MAX_GAUSSIANS)
    """Number of random initial points."""
    points_fn = "splat_framework.model.init:box_points"

    @property
    def planned_points(self) -> int:
        return self.num_points


class FrustumInitConfig(RandomInitConfig):
    """Frustum init: random points inside the training frusta (uniform in inverse depth), coloured by their pixels."""

    kind: Kind[Literal["frustum"]] = "frustum"
    """The init's kind."""
    points_fn = "splat_framework.model.init:frustum_points"


def init_field(*configs: type[InitConfig]):
    """The annotation of an ``init`` field accepting these :class:`InitConfig` kinds, e.g.
    ``init: init_field(RandomInitConfig, MyInitConfig) = Field(default_factory=RandomInitConfig)``.
    The CLI shows the flags of the field's current kind (``--model.init.kind`` switches it)."""
    if len(configs) == 1:
        return Annotated[configs[0], tyro.conf.AvoidSubcommands]
    return Annotated[Union[configs], Field(discriminator="kind"), tyro.conf.AvoidSubcommands]


RandomKinds = init_field(RandomInitConfig, FrustumInitConfig)
"""The random inits, which need nothing but the training views."""


class TriangulatedInitConfig(InitConfig):
    """Triangulated init (the paper's "Triang. init" rows): the training views' matches triangulated with the known poses."""

    kind: Kind[Literal["triangulated"]] = "triangulated"
    """The init's kind."""
    matching: MatchKinds = Field(default_factory=AutoMatchConfig)
    """Matching prior of the triangulation (--model.init.matching.kind K)."""
    max_reprojection_px: Positive = 2.0
    """Drop triangulated points whose reprojection error exceeds this (px)."""
    fallback: RandomKinds = Field(default_factory=RandomInitConfig)
    """The random init used when fewer than 50 matches triangulate."""
    points_fn = "splat_framework.matching.prior:triangulated_init"

    @property
    def planned_points(self) -> int:
        return self.fallback.planned_points


class SfMInitConfig(InitConfig):
    """SfM init: a COLMAP dataset's points3D with their colours (computed from all its photos, test views included)."""

    kind: Kind[Literal["sfm"]] = "sfm"
    """The init's kind."""
    points_fn = "splat_framework.sfm.points:sfm_points"


class PlyInitConfig(InitConfig):
    """PLY init: the centres and base colours of a 3DGS-layout PLY's Gaussians (splat-export's, the 3DGS reference's)."""

    kind: Kind[Literal["ply"]] = "ply"
    """The init's kind."""
    path: Path
    """PLY file to initialise from."""
    points_fn = "splat_framework.model.init:ply_points"


BUILTIN_INITS: dict[str, type[InitConfig]] = {
    c.model_fields["kind"].default: c for c in (RandomInitConfig, FrustumInitConfig, PlyInitConfig)
}
"""The initialisation kinds of the model layer itself, which need nothing but the training views or a file. The
triangulated and SfM kinds, whose points come from the matching and sfm layers above the model, register
through the ``splat_framework.inits`` entry points (the framework's pyproject.toml), as a plugin's kinds do."""


@cache
def init_kinds() -> dict[str, type[InitConfig]]:
    """Every initialisation kind a model accepts unless it narrows its ``init``: the built-ins, then
    the ``splat_framework.inits`` entry points."""
    from ..entry_points import INIT_ENTRY_POINT_GROUP

    return registered_kinds(INIT_ENTRY_POINT_GROUP, "initialisation", InitConfig, BUILTIN_INITS)


def _registered_init(value: Any) -> Any:
    """``value`` (a dict or a config) as the :class:`InitConfig` of its registered kind."""
    return as_registered_kind(value, init_kinds(), "random", "initialisation")


InitKinds = Annotated[SerializeAsAny[InitConfig], BeforeValidator(_registered_init), tyro.conf.AvoidSubcommands]
"""The initialisation kinds every model accepts unless its config narrows them with :func:`init_field`:
the built-ins and every kind of the ``splat_framework.inits`` entry points."""
