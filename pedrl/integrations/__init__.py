"""Adapters from :class:`~pedrl.sim.RoomEnv` to other libraries' environment APIs.

Each adapter is a submodule that imports its library on import, so ``import pedrl`` (which does not import this
package) needs none of them:

- :mod:`pedrl.integrations.pettingzoo`: ``PedestrianParallelEnv``, a PettingZoo ``ParallelEnv`` over one room
  (``pip install pedrl[pettingzoo]``).
- :mod:`pedrl.integrations.jupedsim`: JuPedSim, the field's reference simulator, on a pedrl scenario with the same
  agents and start positions (``pip install pedrl[jupedsim]``; imported when a run starts).
"""
