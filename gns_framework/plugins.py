"""Plugin discovery: a pluggy manager built by a factory, and the component registry.

Plugins are found through the ``gns_framework`` entry-point group (built-ins
included). Each is loaded explicitly: one that fails to load is skipped with one
warning naming its entry point, distribution and exception, and named again by any
error about a component that is then missing (it may have been that plugin's), so one
broken plugin does not stop the commands that do not need it. Every hook
implementation is called once, on its own, so each component (and metric) is known
with the plugin that provides it.

Importing this module loads no component contract (nor torch): the command line
builds its command manager with :func:`make_plugin_manager` before any command runs.
"""

from __future__ import annotations

import importlib.metadata
import inspect
import os
import warnings
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, cast

import pluggy
from pydantic import BaseModel, ValidationError

from . import hookspecs
from .config.problems import problems_from
from .errors import PluginError, PluginWarning, RecipeError, did_you_mean
from .plugin_types import Metric, worst_of
from .specs import ComponentSpec

ENTRY_POINT_GROUP = "gns_framework"
COMMAND_GROUP = "gns_framework.commands"
"""Entry-point group of plugins that add ``gns`` subcommands (:mod:`gns_framework.cli.commands`)."""
DISABLE_ENV = "GNS_DISABLE_PLUGINS"
"""Comma-separated entry-point or distribution names to skip (``*`` skips every plugin)."""


@dataclass(frozen=True)
class ComponentEntry:
    """A registered component and where it comes from."""

    kind: str
    name: str
    cls: type[Any]
    """The component class: a subclass of its kind's contract (``contracts.COMPONENT_KINDS[kind]``), whose class
    attributes (``particle_type``, ``Params``, ...) depend on the kind."""
    plugin: str
    distribution: str
    version: str

    @property
    def source_file(self) -> str:
        try:
            return inspect.getsourcefile(self.cls) or "<unknown>"
        except TypeError:
            return "<built-in>"

    @property
    def provider(self) -> str:
        return f"plugin {self.plugin!r} ({self.distribution} {self.version})"

    @property
    def record(self) -> dict[str, str]:
        """Where it comes from, as a checkpoint stores it: ``{"distribution", "version", "plugin"}``."""
        return {"distribution": self.distribution, "version": self.version, "plugin": self.plugin}


@dataclass(frozen=True)
class MetricEntry:
    """A registered metric and where it comes from."""

    metric: Metric
    plugin: str
    distribution: str
    version: str

    @property
    def provider(self) -> str:
        return f"plugin {self.plugin!r} ({self.distribution} {self.version})"


@dataclass(frozen=True)
class BrokenPlugin:
    """An entry point that raised when it was loaded, so it was skipped.

    Attributes:
        entry_point: its name (what ``$GNS_DISABLE_PLUGINS`` takes).
        value: the module it names.
        distribution, version: the installed package that declares it.
        error: the exception, ``"<type>: <first line of its message>"``.
    """

    entry_point: str
    value: str
    distribution: str
    version: str
    error: str

    @property
    def described(self) -> str:
        return (
            f"plugin entry point {self.entry_point!r} = {self.value!r} of distribution {self.distribution} "
            f"{self.version}"
        )

    def __str__(self) -> str:
        return f"{self.described}, which failed to load ({self.error})"


def disable_one(first: ComponentEntry, second: ComponentEntry) -> str:
    """How to resolve a clash of two components: which plugins to uninstall or disable, and how."""
    return (
        f"uninstall one of them, or disable its plugin with the environment variable "
        f"{DISABLE_ENV}={second.plugin} (or {DISABLE_ENV}={first.plugin})"
    )


class Registry:
    """Components by kind and name, metrics by name, and the plugins that failed to load.

    Built by :func:`load_registry`; immutable afterwards.
    """

    def __init__(
        self,
        entries: Iterable[ComponentEntry],
        metrics: Iterable[MetricEntry] = (),
        broken: Iterable[BrokenPlugin] = (),
    ):
        from .contracts import COMPONENT_KINDS

        self.broken: tuple[BrokenPlugin, ...] = tuple(broken)
        """Entry points skipped because they failed to load, named by errors about missing components."""

        self._entries: dict[str, dict[str, ComponentEntry]] = {kind: {} for kind in COMPONENT_KINDS}
        for entry in entries:
            of_kind = self._entries.setdefault(entry.kind, {})
            if entry.name in of_kind:
                first = of_kind[entry.name]
                raise PluginError(
                    f"two {entry.kind} components are named {entry.name!r}: "
                    f"{first.cls.__module__}.{first.cls.__qualname__} from {first.provider} and "
                    f"{entry.cls.__module__}.{entry.cls.__qualname__} from {entry.provider}; "
                    f"{disable_one(first, entry)}"
                )
            of_kind[entry.name] = entry
        self._check_material_types()
        self._metrics: dict[str, MetricEntry] = {}
        for metric_entry in metrics:
            name = metric_entry.metric.name
            if name in self._metrics:
                raise PluginError(
                    f"two metrics are named {name!r}: from {self._metrics[name].provider} and from "
                    f"{metric_entry.provider}; uninstall one of them, or disable its plugin with the environment "
                    f"variable {DISABLE_ENV}"
                )
            self._metrics[name] = metric_entry
        tracked: dict[str, MetricEntry] = {}
        for metric_entry in self._metrics.values():
            tracked_as = metric_entry.metric.tracked_as
            if tracked_as is None:
                continue
            if tracked_as in tracked:
                first_metric = tracked[tracked_as]
                raise PluginError(
                    f"two metrics are tracked in validation as {tracked_as}: {first_metric.metric.name!r} "
                    f"from {first_metric.provider} and {metric_entry.metric.name!r} from {metric_entry.provider}; "
                    f"uninstall one of them, or disable its plugin with the environment variable {DISABLE_ENV}"
                )
            tracked[tracked_as] = metric_entry

    def _check_material_types(self) -> None:
        seen: dict[int, ComponentEntry] = {}
        for entry in self._entries.get("material", {}).values():
            type_id = entry.cls.particle_type
            if type_id in seen:
                other = seen[type_id]
                raise PluginError(
                    f"materials {other.name!r} from {other.provider} and {entry.name!r} from "
                    f"{entry.provider} both claim particle type {type_id}; {disable_one(other, entry)}"
                )
            seen[type_id] = entry

    def kinds(self) -> list[str]:
        return list(self._entries)

    def names(self, kind: str) -> list[str]:
        return sorted(self._entries.get(kind, {}))

    def entries(self, kind: str | None = None) -> list[ComponentEntry]:
        kinds = [kind] if kind else self.kinds()
        return [e for k in kinds for _, e in sorted(self._entries.get(k, {}).items())]

    def entry(self, kind: str, name: str) -> ComponentEntry:
        if kind not in self._entries:
            raise PluginError(f"unknown component kind {kind!r}; kinds: {', '.join(self.kinds())}")
        try:
            return self._entries[kind][name]
        except KeyError:
            choices = self.names(kind)
            raise PluginError(
                f"unknown {kind} {name!r}{did_you_mean(name, choices)}; installed: "
                f"{', '.join(choices) if choices else 'none'}{self.broken_note()}"
            ) from None

    def broken_note(self) -> str:
        """``"; it may be provided by a plugin that was skipped: <each>"`` for errors about a missing component.

        Empty when no plugin is broken. Which components a broken plugin would have
        provided is unknown (it failed before registering any), so every one is named.
        """
        if not self.broken:
            return ""
        return "; it may be provided by a plugin that was skipped: " + "; ".join(str(b) for b in self.broken)

    def broken_of(self, distribution: str) -> list[BrokenPlugin]:
        """The entry points of ``distribution`` that failed to load."""
        return [b for b in self.broken if b.distribution == distribution]

    def get(self, kind: str, name: str) -> type[Any]:
        return self.entry(kind, name).cls

    def resolve(
        self,
        kind: str,
        spec: ComponentSpec | Mapping[str, Any],
        where: Sequence[str] = (),
        source: str | Path | None = None,
    ) -> tuple[type[Any], BaseModel]:
        """The component class a spec names and its validated ``Params``: the one place names become components.

        Args:
            kind: component kind (``processor``, ``dataset``, ``simulator``, ...).
            spec: a :class:`~gns_framework.specs.ComponentSpec`, or a mapping of ``name``
                and the component's parameters (as read from YAML, before validation).
            where: the spec's location in its file, e.g. ``("model", "processor")``.
            source: the file (or command-line option) the spec comes from.

        Raises:
            RecipeError: at ``<where>.name`` for a name no installed plugin provides (with
                the installed choices), at ``<where>.<param>`` for each bad parameter.
        """
        if isinstance(spec, ComponentSpec):
            name, params = spec.name, spec.params
        else:
            # A string: the callers check it first (config.recipe._component_problems).
            name, params = cast(str, spec.get("name")), {k: v for k, v in spec.items() if k != "name"}
        try:
            cls = self.get(kind, name)
        except PluginError as exc:
            raise RecipeError(source, [(".".join((*where, "name")), str(exc))]) from None
        try:
            return cls, cls.Params.model_validate(params)
        except ValidationError as exc:
            raise RecipeError(source, problems_from(exc, cls.Params, prefix=tuple(where))) from None

    def material_by_type(self, particle_type: int) -> ComponentEntry:
        for entry in self._entries.get("material", {}).values():
            if entry.cls.particle_type == particle_type:
                return entry
        known = ", ".join(f"{e.cls.particle_type}={e.name}" for e in self.entries("material"))
        raise PluginError(f"no installed material has particle type {particle_type}; installed: {known}")

    def material_names(self, particle_types) -> dict[int, str]:
        """Legend labels: each type id's installed material name, ``type <id>`` where none is installed."""
        names = {}
        for particle_type in sorted({int(t) for t in particle_types}):
            try:
                names[particle_type] = self.material_by_type(particle_type).cls.name
            except PluginError:
                names[particle_type] = f"type {particle_type}"
        return names

    def free_particle_types(self) -> list[int]:
        """The valid particle-type ids (``contracts.PARTICLE_TYPE_IDS``) no installed material has.

        A new material takes one of them (``gns plugins`` lists them as ranges).
        """
        from .contracts import PARTICLE_TYPE_IDS

        taken = {e.cls.particle_type for e in self.entries("material")}
        return [i for i in PARTICLE_TYPE_IDS if i not in taken]

    def kinematic_types(self) -> tuple[int, ...]:
        """Particle-type ids of the installed kinematic materials (prescribed, never predicted)."""
        return tuple(sorted(e.cls.particle_type for e in self.entries("material") if e.cls.kinematic))

    def metrics(self) -> list[Metric]:
        """Every installed :class:`~gns_framework.plugin_types.Metric`, in the order the plugins were registered."""
        if not self._metrics:
            raise PluginError(
                "no metric is installed: the built-in ones come from the entry point builtin-metrics of "
                "gns-framework (reinstall it: pip install -e .), and $GNS_DISABLE_PLUGINS may disable it"
                f"{self.broken_note()}"
            )
        return [entry.metric for entry in self._metrics.values()]

    def validation_metrics(self) -> dict[str, Metric]:
        """``valid_rollout_<validation>`` -> metric, for each installed metric measured while training."""
        return {m.tracked_as: m for m in self.metrics() if m.tracked_as is not None}

    def best_metric_choices(self) -> list[str]:
        """What ``training.best_metric`` may name: each tracked error's mean and worst over the validation rollouts."""
        return sorted(name for tracked in self.validation_metrics() for name in (tracked, worst_of(tracked)))

    def metric_entries(self) -> list[MetricEntry]:
        """Every installed metric with its provider, in the order the plugins were registered."""
        return list(self._metrics.values())


def _disabled_names() -> set[str]:
    return {n.strip() for n in os.environ.get(DISABLE_ENV, "").split(",") if n.strip()}


def _warn_unmatched(disabled: set[str]) -> None:
    """One warning naming every name in ``$GNS_DISABLE_PLUGINS`` that is neither an entry point nor a distribution.

    The names a user can give are those of both groups (components and commands),
    listed with their distributions.
    """
    installed: dict[str, set[str]] = {}
    for group in (ENTRY_POINT_GROUP, COMMAND_GROUP):
        for ep in importlib.metadata.entry_points(group=group):
            installed.setdefault(_distribution_of(ep)[0], set()).add(ep.name)
    names = sorted(set(installed) | {name for eps in installed.values() for name in eps})
    unmatched = sorted(disabled - set(names))
    if not unmatched:
        return
    listed = "; ".join(f"{dist}: {', '.join(sorted(eps))}" for dist, eps in sorted(installed.items()))
    warnings.warn(
        f"{DISABLE_ENV}: {', '.join(f'{n!r}{did_you_mean(n, names)}' for n in unmatched)} "
        f"{'names' if len(unmatched) == 1 else 'name'} no installed plugin, so nothing was disabled for "
        f"{'it' if len(unmatched) == 1 else 'them'}; installed plugins (a distribution, then its entry points; "
        f"either name disables): {listed or 'none'}",
        PluginWarning,
        stacklevel=4,
    )


def _distribution_of(ep: importlib.metadata.EntryPoint) -> tuple[str, str]:
    dist = getattr(ep, "dist", None)
    if dist is None:
        return "<unknown distribution>", "?"
    return dist.metadata["Name"], dist.version


def make_plugin_manager(
    load_entry_points: bool = True, plugins: Iterable[tuple[str, object]] = (), group: str = ENTRY_POINT_GROUP
) -> tuple[pluggy.PluginManager, dict[str, tuple[str, str]], list[BrokenPlugin]]:
    """Build a fresh plugin manager (never a shared singleton).

    An entry point that raises when loaded is skipped with one :class:`PluginWarning`
    and returned among the broken ones; the caller names it where a component is missing.

    Args:
        load_entry_points: load every plugin of the entry-point ``group``,
            except those named in ``$GNS_DISABLE_PLUGINS``.
        plugins: extra ``(name, module_or_object)`` plugins to register (tests, embedding).
        group: ``gns_framework`` (components and metrics) or ``gns_framework.commands``.

    Returns:
        The manager; per registered plugin name, its ``(distribution, version)``; the
        entry points that failed to load.
    """
    pm = pluggy.PluginManager(hookspecs.PROJECT)
    pm.add_hookspecs(hookspecs)
    origin: dict[str, tuple[str, str]] = {}
    broken: list[BrokenPlugin] = []
    disabled = _disabled_names()
    if load_entry_points and "*" not in disabled:
        if group == ENTRY_POINT_GROUP:  # the commands' manager is built in the same process: warn once
            _warn_unmatched(disabled)
        for ep in importlib.metadata.entry_points(group=group):
            dist, version = _distribution_of(ep)
            if ep.name in disabled or dist in disabled or pm.has_plugin(ep.name):
                continue
            try:
                plugin = ep.load()
            except Exception as exc:
                message = str(exc).splitlines()[0] if str(exc) else ""
                broken.append(BrokenPlugin(ep.name, ep.value, dist, version, f"{type(exc).__name__}: {message}"))
                warnings.warn(
                    f"{broken[-1].described} failed to load and was skipped: {broken[-1].error}; "
                    f"disable it with {DISABLE_ENV}={ep.name}",
                    PluginWarning,
                    stacklevel=3,
                )
                continue
            _register(pm, ep.name, plugin, f"entry point {ep.name!r} of distribution {dist} {version}")
            origin[ep.name] = (dist, version)
    for name, plugin in plugins:
        _register(pm, name, plugin, f"plugin {name!r}")
        origin[name] = ("<registered in process>", "-")
    return pm, origin, broken


def _register(pm: pluggy.PluginManager, name: str, plugin: object, described: str) -> None:
    try:
        pm.register(plugin, name=name)
    except (pluggy.PluginValidationError, ValueError) as exc:
        raise PluginError(f"{described} is not a valid gns_framework plugin: {exc}") from exc
    try:
        pm.check_pending()
    except pluggy.PluginValidationError as exc:
        raise PluginError(f"{described} implements an unknown hook: {exc}") from exc


def collect_components(
    pm: pluggy.PluginManager, origin: dict[str, tuple[str, str]], broken: Iterable[BrokenPlugin] = ()
) -> Registry:
    """Call every hook implementation once and build the registry from what it returns (and the ``broken`` plugins)."""
    from .contracts import COMPONENT_KINDS

    entries: list[ComponentEntry] = []
    for kind, contract in COMPONENT_KINDS.items():
        hook_name = hookspecs.hook_of_kind(kind)
        for impl, where, classes in hook_results(pm, origin, hook_name):
            for cls in classes:
                if not (inspect.isclass(cls) and issubclass(cls, contract)):
                    raise PluginError(f"{where} returned {cls!r}, which is not a subclass of {contract.__name__}")
                name = getattr(cls, "name", None)
                if not isinstance(name, str) or not name:
                    raise PluginError(f"{where}: {cls.__qualname__} has no string class attribute 'name'")
                dist, version = origin.get(impl.plugin_name, ("<unknown distribution>", "?"))
                entries.append(ComponentEntry(kind, name, cls, impl.plugin_name, dist, version))
    metrics = []
    for impl, where, records in hook_results(pm, origin, "gns_metrics"):
        for metric in records:
            if not isinstance(metric, Metric):
                raise PluginError(f"{where} returned {metric!r}, which is not a gns_framework.plugin_types.Metric")
            dist, version = origin.get(impl.plugin_name, ("<unknown distribution>", "?"))
            metrics.append(MetricEntry(metric, impl.plugin_name, dist, version))
    return Registry(entries, metrics, broken)


def hook_results(
    pm: pluggy.PluginManager, origin: dict[str, tuple[str, str]], hook_name: str
) -> list[tuple[pluggy.HookImpl, str, list | tuple]]:
    """``(implementation, where, returned list)`` of every implementation of ``hook_name``, each called once."""
    results: list[tuple[pluggy.HookImpl, str, list | tuple]] = []
    for impl in getattr(pm.hook, hook_name).get_hookimpls():
        dist, version = origin.get(impl.plugin_name, ("<unknown distribution>", "?"))
        where = f"plugin {impl.plugin_name!r} ({dist} {version}), hook {hook_name}"
        try:
            returned = impl.function()
        except Exception as exc:
            raise PluginError(f"{where} raised {type(exc).__name__}: {exc}") from exc
        if not isinstance(returned, (list, tuple)):
            raise PluginError(f"{where} must return a list, got {type(returned).__name__}")
        results.append((impl, where, returned))
    return results


def load_registry(load_entry_points: bool = True, plugins: Iterable[tuple[str, object]] = ()) -> Registry:
    """Discover installed plugins (plus ``plugins``) and return their components; broken plugins are skipped."""
    return collect_components(*make_plugin_manager(load_entry_points, plugins))
