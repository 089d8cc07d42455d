"""Built-in components of gns-framework: the reference GNS (Sanchez-Gonzalez et al. 2020).

Every sub-package is a plugin registered through the ``gns_framework`` entry-point
group, exactly as a third-party package would be.
"""
