"""pedrl: multi-agent vector-quantised Q-learning for pedestrian navigation.

A learned crowd, without Hydra or a trainer::

    import pedrl

    policy = pedrl.load_policy("policy.safetensors")      # a training checkpoint, or a file of pedrl-export
    policy = pedrl.load_policy(pedrl.pretrained("main"))  # or a policy shipped with pedrl
    actions = policy.act(obs, info, epsilon=0.1, generator=generator)   # obs (R, N, F), info: as RoomEnv gives
"""

from typing import Any

from pedrl.version import __version__

__all__ = ["NeuralPolicy", "TabularPolicy", "__version__", "export_policy", "load_policy", "pretrained", "room_factory"]


def __getattr__(name: str) -> Any:
    """``load_policy``, ``export_policy``, ``room_factory``, ``pretrained`` (:mod:`pedrl.policy_files`) and
    ``TabularPolicy`` and ``NeuralPolicy``, imported on first use: ``import pedrl`` stays light (the entry points
    import what they need)."""
    if name in ("load_policy", "export_policy", "room_factory", "pretrained"):
        import pedrl.policy_files

        return getattr(pedrl.policy_files, name)
    if name == "TabularPolicy":
        from pedrl.rl.policy import TabularPolicy

        return TabularPolicy
    if name == "NeuralPolicy":
        from pedrl.rl.neural import NeuralPolicy

        return NeuralPolicy
    raise AttributeError(f"module 'pedrl' has no attribute {name!r}")
