"""Importers of checkpoints written by other GNS implementations.

Each importer turns a foreign checkpoint into a simulator built from the built-in
components, plus everything a gns-framework checkpoint stores (recipe, scene,
metadata), so ``gns rollout`` and ``gns train --resume`` work on the result.
"""
