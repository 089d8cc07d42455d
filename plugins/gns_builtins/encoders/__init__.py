"""Built-in encoders."""

from gns_framework.api import hookimpl

from .mlp import MLPEncoder


@hookimpl
def gns_encoders():
    return [MLPEncoder]
