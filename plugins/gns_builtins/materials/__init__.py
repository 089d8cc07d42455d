"""Built-in materials, one per file, with the particle-type ids of the public GNS datasets."""

from gns_framework.api import hookimpl

from .goop import Goop
from .rigid import RigidBoundary
from .sand import FRICTION, Sand
from .water import Water

__all__ = ["FRICTION", "Goop", "RigidBoundary", "Sand", "Water"]


@hookimpl
def gns_materials():
    return [RigidBoundary, Water, Sand, Goop]
