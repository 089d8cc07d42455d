"""Example gns-framework plugin: the processor ``mean_interaction_network``.

Registered through the ``gns_framework`` entry-point group in this package's
pyproject.toml; gns-framework finds it when the package is installed.
"""

from gns_framework.api import hookimpl

from .mean_interaction import MeanInteractionNetwork


@hookimpl
def gns_processors():
    return [MeanInteractionNetwork]
