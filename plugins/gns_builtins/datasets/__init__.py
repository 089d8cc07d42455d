"""Built-in dataset layouts."""

from gns_framework.hookspecs import hookimpl

from .geoelements_npz import GeoelementsNpzDataset
from .lagrangebench import LagrangeBenchDataset
from .safe import SafeDataset
from .tfrecord import TfRecordDataset


@hookimpl
def gns_datasets():
    return [SafeDataset, GeoelementsNpzDataset, TfRecordDataset, LagrangeBenchDataset]
