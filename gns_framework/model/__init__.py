"""The learned simulator, as Sanchez-Gonzalez et al. (2020) describe it.

- :mod:`.learned_simulator`: positions -> graph -> encode, process, decode -> integrate;
- :mod:`.features`: node features (velocity history, wall distances, type, properties) and edge features;
- :mod:`.normalization`: statistics that put inputs and targets on unit scale;
- :mod:`.noise`: the random-walk noise added to the input history in training;
- :mod:`.loss`: the training loss on normalised accelerations (or velocities);
- :mod:`.periodic`: the periodic box (minimum-image displacements, wrapping);
- :mod:`.rollout` and :mod:`.rollout_guard`: autoregressive rollouts, checked frame by frame.

The components it puts together (graph builder, encoder, processor, decoder,
integrator) are plugins; :mod:`gns_framework.assembly.learned` builds it from a recipe.
"""
