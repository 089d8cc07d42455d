"""Built-in dataset layouts."""

from gns_framework.api import hookimpl

from .lagrangebench import LagrangeBenchDataset
from .npz import GeoelementsNpzDataset
from .safe import SafeDataset
from .tfrecord import TfRecordDataset


@hookimpl
def gns_datasets():
    return [SafeDataset, GeoelementsNpzDataset, TfRecordDataset, LagrangeBenchDataset]
