"""Example gns-framework plugin: cohesive clay.

Registered through the ``gns_framework`` entry-point group in this package's
pyproject.toml; gns-framework finds it when the package is installed.
"""

from gns_framework.api import hookimpl

from .clay import Clay


@hookimpl
def gns_materials():
    return [Clay]
