"""Numerical stability: stiff test problems, measurements on them, and extreme inputs for the learned simulator.

- :mod:`.problems`: force laws with known answers (spring chain, stiff repulsive collision).
- :mod:`.measure`: energy drift and time-step stability limits of an integrator's ``advance``.
- :mod:`.extreme`: scenes that stress the learned simulator (walls, coincident and
  isolated particles, dense clusters, huge velocities, zero statistics, bfloat16).
- :mod:`.report`: every case with its outcome and figures (``gns stability``).

Figures are documented in ``docs/stability.md``.
"""
