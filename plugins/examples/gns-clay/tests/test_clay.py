"""The clay material conforms and is found through its entry point."""

from gns_framework.plugins import load_registry
from gns_framework.testing import check_material

from gns_example_clay import Clay


def test_clay_conforms():
    check_material(Clay)


def test_clay_is_registered_by_its_entry_point():
    entry = load_registry().entry("material", "clay")
    assert entry.cls is Clay
    assert entry.distribution == "gns-example-clay"
