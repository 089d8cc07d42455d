"""Built-in decoders."""

from gns_framework.api import hookimpl

from .mlp import MLPDecoder


@hookimpl
def gns_decoders():
    return [MLPDecoder]
