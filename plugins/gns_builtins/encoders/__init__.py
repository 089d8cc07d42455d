"""Built-in encoders."""

from gns_framework.hookspecs import hookimpl

from .mlp import MLPEncoder


@hookimpl
def gns_encoders():
    return [MLPEncoder]
