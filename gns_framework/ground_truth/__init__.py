"""Ground truth: scene files (``scenes/*.yaml``), their sampling and checks, and dataset generation.

The simulators themselves are plugins (``mls_mpm`` in gns_builtins);
:mod:`gns_framework.assembly.ground_truth` builds the one a scene names.
"""
