"""Built-in ground-truth simulators (Warp is imported only when one runs)."""

from gns_framework.api import hookimpl

from .mls_mpm import MlsMpm


@hookimpl
def gns_simulators():
    return [MlsMpm]
