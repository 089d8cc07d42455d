"""gns-framework: a plugin-based Graph Network Simulator for learned particle dynamics.

Importing the package is cheap on purpose: heavy optional dependencies (MLflow,
VTK writers, simulators) are imported only by the commands that use them.
"""

__version__ = "0.1.0"
