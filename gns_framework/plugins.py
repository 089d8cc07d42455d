"""Plugin discovery: a pluggy manager built by a factory, and the component registry.

Plugins are found through the ``gns_framework`` entry-point group (built-ins
included). Each is loaded explicitly so a failure names its entry point and
distribution; every hook implementation is called once, on its own, so each
component (and metric) is known with the plugin that provides it.

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
from typing import Any

import pluggy
from pydantic import BaseModel, ValidationError

from . import hookspecs
from .config.problems import problems_from
from .errors import PluginError, RecipeError, did_you_mean
from .plugin_types import Metric
from .specs import ComponentSpec

ENTRY_POINT_GROUP = "gns_framework"
DISABLE_ENV = "GNS_DISABLE_PLUGINS"
"""Comma-separated entry-point or distribution names to skip (``*`` skips every plugin)."""


@dataclass(frozen=True)
class ComponentEntry:
    """A registered component and where it comes from."""

    kind: str
    name: str
    cls: type
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


def disable_one(first: ComponentEntry, second: ComponentEntry) -> str:
    """How to resolve a clash of two components: which plugins to uninstall or disable, and how."""
    return (
        f"uninstall one of them, or disable its plugin with the environment variable "
        f"{DISABLE_ENV}={second.plugin} (or {DISABLE_ENV}={first.plugin})"
    )


class Registry:
    """Components by kind and name, and metrics by name. Built by :func:`load_registry`; immutable afterwards."""

    def __init__(self, entries: Iterable[ComponentEntry], metrics: Iterable[tuple[Metric, str]] = ()):
        """``metrics``: (:class:`~gns_framework.plugin_types.Metric`, provider) pairs."""
        from .contracts import COMPONENT_KINDS

        self._entries: dict[str, dict[str, ComponentEntry]] = {kind: {} for kind in COMPONENT_KINDS}
        for entry in entries:
            of_kind = self._entries.setdefault(entry.kind, {})
            if entry.name in of_kind:
                first = of_kind[entry.name]
                raise PluginError(
                    f"two {entry.kind} components are named {entry.name!r}: "
                    f"{first.cls.__module__}.{first.cls.__qualname__} from {first.provider} and "
                    f"{entry.cls.__module__}.{entry.cls.__qualname__} from {entry.provider}; {disable_one(first, entry)}"
                )
            of_kind[entry.name] = entry
        self._check_material_types()
        self._metrics: dict[str, tuple[Metric, str]] = {}
        for metric, provider in metrics:
            if metric.name in self._metrics:
                raise PluginError(
                    f"two metrics are named {metric.name!r}: from {self._metrics[metric.name][1]} and from {provider}; "
                    f"uninstall one of them, or disable its plugin with the environment variable {DISABLE_ENV}"
                )
            self._metrics[metric.name] = (metric, provider)

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
                f"{', '.join(choices) if choices else 'none'}"
            ) from None

    def get(self, kind: str, name: str) -> type:
        return self.entry(kind, name).cls

    def resolve(
        self,
        kind: str,
        spec: ComponentSpec | Mapping[str, Any],
        where: Sequence[str] = (),
        source: str | Path | None = None,
    ) -> tuple[type, BaseModel]:
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
            name, params = spec.get("name"), {k: v for k, v in spec.items() if k != "name"}
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

    def kinematic_types(self) -> tuple[int, ...]:
        """Particle-type ids of the installed kinematic materials (prescribed, never predicted)."""
        return tuple(sorted(e.cls.particle_type for e in self.entries("material") if e.cls.kinematic))

    def metrics(self) -> list[Metric]:
        """Every installed :class:`~gns_framework.plugin_types.Metric`, in the order the plugins were registered."""
        if not self._metrics:
            raise PluginError(
                "no metric is installed: the built-in ones come from the entry point builtin-metrics of "
                "gns-framework (reinstall it: pip install -e .), and $GNS_DISABLE_PLUGINS may disable it"
            )
        return [metric for metric, _ in self._metrics.values()]

    def version_of(self, kind: str, name: str) -> str:
        entry = self.entry(kind, name)
        return f"{entry.distribution} {entry.version}"


def _disabled_names() -> set[str]:
    return {n.strip() for n in os.environ.get(DISABLE_ENV, "").split(",") if n.strip()}


def _warn_unmatched(disabled: set[str], entry_points: Iterable[importlib.metadata.EntryPoint]) -> None:
    """Warn about each name in ``$GNS_DISABLE_PLUGINS`` that is neither an entry point nor a distribution."""
    entry_names = sorted({ep.name for ep in entry_points})
    distributions = sorted({_distribution_of(ep)[0] for ep in entry_points})
    for name in sorted(disabled - set(entry_names) - set(distributions)):
        warnings.warn(
            f"{DISABLE_ENV}: {name!r} names no installed plugin{did_you_mean(name, entry_names + distributions)}, "
            f"so nothing was disabled for it; entry points: {', '.join(entry_names)}; "
            f"distributions: {', '.join(distributions)}",
            stacklevel=3,
        )


def _distribution_of(ep: importlib.metadata.EntryPoint) -> tuple[str, str]:
    dist = getattr(ep, "dist", None)
    if dist is None:
        return "<unknown distribution>", "?"
    return dist.metadata["Name"], dist.version


def make_plugin_manager(
    load_entry_points: bool = True, plugins: Iterable[tuple[str, object]] = (), group: str = ENTRY_POINT_GROUP
) -> tuple[pluggy.PluginManager, dict[str, tuple[str, str]]]:
    """Build a fresh plugin manager (never a shared singleton).

    Args:
        load_entry_points: load every plugin of the entry-point ``group``,
            except those named in ``$GNS_DISABLE_PLUGINS``.
        plugins: extra ``(name, module_or_object)`` plugins to register (tests, embedding).
        group: ``gns_framework`` (components and metrics) or ``gns_framework.commands``.

    Returns:
        The manager and, per registered plugin name, its ``(distribution, version)``.
    """
    pm = pluggy.PluginManager(hookspecs.PROJECT)
    pm.add_hookspecs(hookspecs)
    origin: dict[str, tuple[str, str]] = {}
    disabled = _disabled_names()
    if load_entry_points and "*" not in disabled:
        entry_points = importlib.metadata.entry_points(group=group)
        _warn_unmatched(disabled, entry_points)
        for ep in entry_points:
            dist, version = _distribution_of(ep)
            if ep.name in disabled or dist in disabled or pm.has_plugin(ep.name):
                continue
            try:
                plugin = ep.load()
            except Exception as exc:
                raise PluginError(
                    f"plugin entry point {ep.name!r} = {ep.value!r} of distribution {dist} {version} "
                    f"failed to load: {type(exc).__name__}: {exc}. Disable it with {DISABLE_ENV}={ep.name}"
                ) from exc
            _register(pm, ep.name, plugin, f"entry point {ep.name!r} of distribution {dist} {version}")
            origin[ep.name] = (dist, version)
    for name, plugin in plugins:
        _register(pm, name, plugin, f"plugin {name!r}")
        origin[name] = ("<registered in process>", "-")
    return pm, origin


def _register(pm: pluggy.PluginManager, name: str, plugin: object, described: str) -> None:
    try:
        pm.register(plugin, name=name)
    except (pluggy.PluginValidationError, ValueError) as exc:
        raise PluginError(f"{described} is not a valid gns_framework plugin: {exc}") from exc
    try:
        pm.check_pending()
    except pluggy.PluginValidationError as exc:
        raise PluginError(f"{described} implements an unknown hook: {exc}") from exc


def collect_components(pm: pluggy.PluginManager, origin: dict[str, tuple[str, str]]) -> Registry:
    """Call every hook implementation once and build the registry from what it returns."""
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
    for _, where, records in hook_results(pm, origin, "gns_metrics"):
        for metric in records:
            if not isinstance(metric, Metric):
                raise PluginError(f"{where} returned {metric!r}, which is not a gns_framework.plugin_types.Metric")
            metrics.append((metric, where))
    return Registry(entries, metrics)


def hook_results(
    pm: pluggy.PluginManager, origin: dict[str, tuple[str, str]], hook_name: str
) -> list[tuple[object, str, list | tuple]]:
    """``(implementation, where, returned list)`` of every implementation of ``hook_name``, each called once."""
    results = []
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
    """Discover installed plugins (plus ``plugins``) and return their components."""
    pm, origin = make_plugin_manager(load_entry_points, plugins)
    return collect_components(pm, origin)
