"""Built-in dataset layouts."""

from gns_framework.hookspecs import hookimpl

from .geoelements_npz import GeoelementsNpzDataset
from .safe import SafeDataset


@hookimpl
def gns_datasets():
    return [SafeDataset, GeoelementsNpzDataset]
