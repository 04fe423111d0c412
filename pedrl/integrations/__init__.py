"""Adapters from :class:`~pedrl.sim.RoomEnv` to other libraries' environment APIs.

Each adapter is a submodule that imports its library on import, so ``import pedrl`` (which does not import this
package) needs none of them:

- :mod:`pedrl.integrations.pettingzoo`: ``PedestrianParallelEnv``, a PettingZoo ``ParallelEnv`` over one room
  (``pip install pedrl[pettingzoo]``).
"""
