"""Built-in integrators."""

from gns_framework.hookspecs import hookimpl

from .semi_implicit_euler import SemiImplicitEuler


@hookimpl
def gns_integrators():
    return [SemiImplicitEuler]
