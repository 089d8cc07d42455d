"""Built-in integrators."""

from gns_framework.api import hookimpl

from .explicit_euler import ExplicitEuler
from .semi_implicit_euler import SemiImplicitEuler
from .velocity_euler import VelocityEuler
from .velocity_verlet import VelocityVerlet


@hookimpl
def gns_integrators():
    return [SemiImplicitEuler, ExplicitEuler, VelocityVerlet, VelocityEuler]
