"""Assembly: the one place where recipe and scene names become components.

Names resolve through :meth:`gns_framework.plugins.Registry.resolve`; this package
puts the resolved components together:

- :mod:`.data`: a recipe's dataset, opened and strided, with the scene it gives;
- :mod:`.scene`: the scene a learned model is sized for, derived from data (and stored in checkpoints);
- :mod:`.learned`: the learned simulator a recipe's ``model`` names;
- :mod:`.trained`: a trained learned simulator, rebuilt from its checkpoint;
- :mod:`.ground_truth`: the ground-truth simulator a scene file names.
"""
