"""Built-in decoders."""

from gns_framework.hookspecs import hookimpl

from .mlp import MLPDecoder


@hookimpl
def gns_decoders():
    return [MLPDecoder]
