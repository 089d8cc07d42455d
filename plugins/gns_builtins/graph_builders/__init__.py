"""Built-in graph builders."""

from gns_framework.hookspecs import hookimpl

from .radius import RadiusGraphBuilder


@hookimpl
def gns_graph_builders():
    return [RadiusGraphBuilder]
