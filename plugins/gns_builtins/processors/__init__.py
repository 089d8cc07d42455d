"""Built-in processors."""

from gns_framework.hookspecs import hookimpl

from .interaction_network import InteractionNetwork


@hookimpl
def gns_processors():
    return [InteractionNetwork]
