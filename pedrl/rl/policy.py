"""A learned policy you can carry: a state encoder, the Q tables, and the rule that gives each agent its table.

:class:`TabularPolicy` is what training learns and what evaluation, validation and the PettingZoo adapter run.
It needs no trainer and no config: ``pedrl-export`` writes one to a small file (:meth:`TabularPolicy.save`) and
:meth:`TabularPolicy.load` (or :func:`pedrl.load_policy`, which also reads training checkpoints) reads it back.

The agent-to-table rule (:class:`TableLayout`): replica ``i`` of a room is driven by learning process
``p = (i // E) mod P`` and agent ``n`` of every replica by table ``a = n mod A`` of that process, where ``P`` and
``A`` are the stored processes and tables and ``E`` the rooms per process. Training runs ``P E`` replicas with
its ``rooms_per_process = E`` (rooms ``p E .. p E + E - 1`` learn into process ``p``); a loaded policy has
``E = 1``: replica ``i`` takes process ``i mod P``, so a batch of trials cycles through every learned process.
A room with more agents than were learned reuses the tables: with ``A = 20``, agents 20, 40, ... act with table 0.
"""

from __future__ import annotations

import functools
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any, ClassVar, Final, NamedTuple, Protocol, runtime_checkable

import numpy as np
import torch

from pedrl.common.checks import check_integer, check_number, first_line, shown
from pedrl.io import CheckpointError, load_checkpoint, save_checkpoint
from pedrl.rl.qtable import NUM_ACTIONS, epsilon_greedy, table_rows
from pedrl.vq.encoder import EncoderSettings, StateEncoder, quantizer_from_state_dict
from pedrl.vq.quantizer import Quantizer

POLICY_KIND: Final = "pedrl-policy"
"""``kind`` of an exported policy file's metadata (a training checkpoint has none)."""
POLICY_VERSION: Final = 1
"""``policy_version`` of the files this pedrl writes and reads."""
FILE_KEYS: Final = ("format", "format_version", "pedrl_version", "kind", "policy_version", "learner", "encoder")
"""Metadata keys a policy file writes itself; the others are the policy's own ``metadata``."""
TABLE_LEARNER: Final = "table"
"""``learner`` of a policy file of tables (files written before the key have none and are read as tables)."""
QUANTIZER_PREFIX: Final = "quantizer"
QUANTIZER_DTYPES: Final = {
    "mean": torch.float32,
    "std": torch.float32,
    "prototypes": torch.float32,
    "feature_index": torch.int64,
    "num_sensed": torch.int64,
    "slots": torch.int64,
}
"""dtype of every quantizer tensor, by the last part of its name (``process000/part3.prototypes``)."""


@runtime_checkable
class LearnedPolicy(Protocol):
    """What ``pedrl-eval``, ``pedrl-validate``, the PettingZoo adapter, the tools and ``pedrl-export`` take of a
    learned policy, whatever learned it (:class:`TabularPolicy` and :class:`pedrl.rl.NeuralPolicy` are two).

    A policy acts on the room's observations (``act``, or as a controller of the evaluation engine), carries plain
    ``metadata``, names its ``learner`` (the key of its file reader, :data:`POLICY_READERS`), and gives its state as
    named tensors (``tensors``), which :func:`write_policy_file` writes and :func:`read_policy_file` reads back.
    It hands itself to the compiled trial: ``kernel_reason(env)`` says why the fused trial cannot run it in ``env``
    (None where it can, the room's own reasons aside), and ``kernel_arrays()`` gives what the fused trial reads of
    it, packed once per quantizer (:class:`KernelArrays`), or None for a policy that acts in torch between compiled
    steps of the room (a network: :class:`pedrl.trial.stepped.CompiledRoom`).
    """

    learner: ClassVar[str]
    metadata: dict[str, Any]
    encoder: StateEncoder

    @property
    def num_processes(self) -> int: ...

    @property
    def num_actions(self) -> int: ...

    @property
    def device(self) -> torch.device: ...

    def act(
        self,
        obs: torch.Tensor,
        info: Mapping[str, Any],
        *,
        epsilon: float = 0.0,
        generator: torch.Generator | None = None,
    ) -> torch.Tensor: ...

    def controller(self, epsilon: float = 0.0, generator: torch.Generator | None = None) -> Any: ...

    def check(self, num_actions: int | None = None) -> None: ...

    def tensors(self) -> dict[str, torch.Tensor]: ...

    def save(self, path: str | Path) -> Path: ...

    def kernel_reason(self, env: Any) -> str | None: ...

    def kernel_arrays(self) -> KernelArrays | None: ...


class KernelArrays(NamedTuple):
    """A policy as the fused trial reads it (:meth:`TabularPolicy.kernel_arrays`): its quantizer packed for the
    encoding kernels (:func:`pedrl.vq.encode_kernel.pack_encoder`, a stub of one prototype under a factored table),
    a factored quantizer's arrays (:func:`pedrl.vq.factored_kernel.pack_factored`, a stub of no slots otherwise), the
    encoder's settings as the kernels read them, and the tables ``(P A K, U)`` as a view of the policy's own (the
    learning trial updates them in place)."""

    encoder: Any
    factored: Any
    settings: Any
    table: np.ndarray


PolicyReader = Callable[..., LearnedPolicy]
"""``reader(settings, tensors, *, num_actions, metadata)``: a checked policy from a file's encoder settings, tensors
and carried metadata (one-line ``ValueError`` otherwise)."""
POLICY_READERS: Final[dict[str, PolicyReader]] = {}
"""The file reader of each ``learner`` (:func:`register_learner`)."""


def register_learner(learner: str, reader: PolicyReader) -> None:
    """Make policy files of ``learner`` readable by :func:`read_policy_file` (and so by :func:`pedrl.load_policy`)."""
    POLICY_READERS[learner] = reader


def check_learner(learner: Any) -> str:
    """``learner``, a file's stored learner, if a reader of :data:`POLICY_READERS` takes it; one-line ``ValueError``
    otherwise (a crafted value of any type included)."""
    if not isinstance(learner, str) or learner not in POLICY_READERS:
        raise ValueError(f"metadata learner={shown(learner)} is unknown: allowed: {', '.join(POLICY_READERS)}")
    return learner


def write_policy_file(policy: LearnedPolicy, path: str | Path) -> Path:
    """Write ``policy``'s tensors, its encoder settings, its learner and its metadata to ``path`` (atomically;
    safetensors): the one policy file of every learner."""
    tensors = {name: tensor.contiguous() for name, tensor in policy.tensors().items()}
    metadata = {
        **{key: value for key, value in policy.metadata.items() if key not in FILE_KEYS},
        "kind": POLICY_KIND,
        "policy_version": POLICY_VERSION,
        "learner": policy.learner,
        "encoder": policy.encoder.settings.to_metadata(),
    }
    save_checkpoint(Path(path), tensors=tensors, metadata=metadata)
    return Path(path)


def read_policy_file(
    path: str | Path, *, device: str | torch.device = "cpu", learner: str | None = None
) -> LearnedPolicy:
    """Read a policy file of :func:`write_policy_file` (``pedrl-export``) with its learner's reader: nothing in it is
    executed, and every tensor and setting is checked. ``learner``: accept only that learner's files.

    Raises:
        CheckpointError: one line naming the file and what is wrong.
    """
    checkpoint = load_checkpoint(path, device=device)
    meta = checkpoint.metadata
    if meta.get("kind") != POLICY_KIND:
        raise CheckpointError(
            f"{str(path)!r} is not an exported policy (metadata kind={meta.get('kind')!r}, must be "
            f"{POLICY_KIND!r}): export a training checkpoint with pedrl-export, or load it with pedrl.load_policy"
        )
    try:
        found = check_learner(meta.get("learner", TABLE_LEARNER))
    except ValueError as err:
        raise CheckpointError(f"policy {str(path)!r}: {err}") from None
    if learner is not None and found != learner:
        raise CheckpointError(
            f"{str(path)!r} is a policy of learner {found!r}, not {learner!r}: load it with pedrl.load_policy"
        )
    try:
        settings = check_policy_header(meta)
        carried = {key: value for key, value in meta.items() if key not in FILE_KEYS}
        return POLICY_READERS[found](settings, checkpoint.tensors, num_actions=NUM_ACTIONS, metadata=carried)
    except ValueError as err:
        raise CheckpointError(f"policy {str(path)!r}: {err}") from None


class TableLayout:
    """The agent-to-table rule: replica ``i`` -> process ``(i // E) mod P``, agent ``n`` -> table ``n mod A``.

    Args:
        processes: P, learning processes stored in the tables.
        tables: A, tables per process.
        num_states: K, rows per table.
        rooms_per_process: E, consecutive replicas per process.
    """

    def __init__(self, processes: int, tables: int, num_states: int, rooms_per_process: int = 1) -> None:
        self.processes, self.tables, self.num_states = processes, tables, num_states
        self.rooms_per_process = check_integer("rooms_per_process", rooms_per_process, minimum=1)
        self._cache: dict[tuple[int, int, torch.device], tuple[torch.Tensor, torch.Tensor]] = {}

    def blocks(self, replicas: int) -> bool:
        """True when ``replicas`` rooms are exactly ``E`` consecutive rooms per process, in order: the trainers'
        layout, which per-process quantizers encode without being told the processes."""
        return replicas == self.processes * self.rooms_per_process

    def of(self, replicas: int, agents: int, device: torch.device) -> tuple[torch.Tensor, torch.Tensor]:
        """``(process (R * N,), rows (R * N,))``: every agent's process and the first row ``(p A + a) K`` of its
        table in ``q_values.view(-1, U)``, flat, replica-major; cached per room shape."""
        key = (replicas, agents, device)
        if key not in self._cache:
            replica = torch.arange(replicas, device=device)
            process = torch.div(replica, self.rooms_per_process, rounding_mode="floor").remainder(self.processes)
            process = process.repeat_interleave(agents)
            table = torch.arange(agents, device=device).remainder(self.tables).repeat(replicas)
            rows = table_rows(process, table, 0, num_tables=self.tables, num_states=self.num_states)
            self._cache[key] = (process, rows)
        return self._cache[key]


@functools.lru_cache(maxsize=8)
def one_state_encoder(settings: EncoderSettings) -> StateEncoder:
    """An encoder of one state (a single zero prototype) for ``settings``, built once per settings: what the fused
    trial's encoding arrays hold where no plain quantizer is read (the greedy walker's trial, a factored table)."""
    width = settings.num_features
    return StateEncoder(
        settings, Quantizer(mean=torch.zeros(width), std=torch.ones(width), prototypes=torch.zeros(1, width))
    )


class TabularPolicy:
    """Acts epsilon-greedily on learned tables ``q_values (P, A, K, U)`` over ``encoder``'s state ids (a
    :class:`LearnedPolicy` of learner :data:`TABLE_LEARNER`).

    Args:
        encoder: observation -> state id (its quantizer has K prototypes per process).
        q_values: ``(P, A, K, U)`` float32 tables: P processes, A tables each, K states, U actions.
        rooms_per_process: E of the agent-to-table rule (module docstring); 1 for a loaded policy.
        metadata: plain values carried with the policy (the algorithm, the room it learned in).
    """

    learner: ClassVar[str] = TABLE_LEARNER

    def __init__(
        self,
        encoder: StateEncoder,
        q_values: torch.Tensor,
        *,
        rooms_per_process: int = 1,
        metadata: Mapping[str, Any] | None = None,
    ) -> None:
        if q_values.ndim != 4:
            raise ValueError(f"q_values must have shape (P, A, K, U), got {tuple(q_values.shape)}")
        self.encoder = encoder
        self.q_values = q_values
        self.metadata = dict(metadata or {})
        processes, tables, num_states, _ = q_values.shape
        self.layout = TableLayout(processes, tables, num_states, rooms_per_process)
        self._generator: torch.Generator | None = None  # act's, when none is given: one stream of draws

    @property
    def num_processes(self) -> int:
        """P, the learning processes stored in the tables."""
        return self.q_values.shape[0]

    @property
    def num_tables(self) -> int:
        """A, the learned tables per process."""
        return self.q_values.shape[1]

    @property
    def num_actions(self) -> int:
        """U, the actions."""
        return self.q_values.shape[-1]

    @property
    def device(self) -> torch.device:
        return self.q_values.device

    def kernel_reason(self, env: Any) -> str | None:
        """Why the fused trial cannot run these tables in ``env`` (one phrase), or None (the room's own reasons
        aside: :func:`pedrl.trial.crowd.choose_path`)."""
        if self.device.type != "cpu":
            return f"on {self.device.type}: it runs on the CPU"
        settings = self.encoder.settings
        if (env.params.num_neighbours, env.params.num_walls) != (settings.num_neighbours, settings.num_walls):
            return "in a room that senses other neighbour or wall slots than the encoder reads"
        quantizer = self.encoder.quantizer
        if quantizer is None:
            return "with an encoder that has no quantizer"
        parts = getattr(quantizer, "num_processes", self.num_processes)
        if parts != self.num_processes or quantizer.num_prototypes != self.q_values.shape[2]:
            return "with tables that do not match the quantizer (processes or prototypes)"
        if self.q_values.dtype != torch.float32 or not self.q_values.is_contiguous():
            return "with tables that are not contiguous float32"
        return None

    def kernel_arrays(self) -> KernelArrays:
        """These tables as the fused trial reads them (:class:`KernelArrays`; the quantizer packed once, however
        many policies share it)."""
        from pedrl.vq.encode_kernel import pack_encoder
        from pedrl.vq.factored_kernel import pack_factored

        factored = pack_factored(self.encoder)
        plain = one_state_encoder(self.encoder.settings) if factored.num_slots else self.encoder
        return KernelArrays(
            pack_encoder(plain, self.num_processes),
            factored,
            self.encoder.settings.kernel(),
            self.q_values.view(-1, self.num_actions).numpy(),
        )

    def rows(
        self,
        obs: torch.Tensor,
        info: Mapping[str, Any],
        generator: torch.Generator,
        *,
        rows_mask: torch.Tensor | None = None,
    ) -> torch.Tensor:
        """Flat rows ``(R * N,)`` of every agent's state in ``q_values.view(-1, U)`` for observations
        ``(R, N, F)`` (row sets ``(R * N, M)``, -1 for an empty slot, of a factored table); with ``rows_mask
        (R * N,)`` only those agents are encoded (the others get their table's first row, or an empty set).
        ``generator`` draws random void fillings."""
        replicas, agents = obs.shape[0], obs.shape[1]
        process, base_rows = self.layout.of(replicas, agents, obs.device)
        implicit = self.layout.blocks(replicas)  # the trainers' layout: the quantizers need not be told
        ids = self.encoder.encode(
            obs, info, generator, None if implicit else process, rows_mask=rows_mask, process_of_rows=process
        )
        return offset_ids(base_rows, ids)

    def act(
        self,
        obs: torch.Tensor,
        info: Mapping[str, Any],
        *,
        epsilon: float = 0.0,
        generator: torch.Generator | None = None,
    ) -> torch.Tensor:
        """Actions ``(R, N)`` int64 for observations ``obs (R, N, F)`` and ``info`` (as ``RoomEnv`` returns them).

        ``epsilon`` in ``[0, 1]`` is the share of random actions (0: greedy, ties broken at random); ``generator``
        (on the tables' device) draws them, the ties and random void fillings: pass a seeded one for reproducible
        runs (None: the policy's own, seeded from the system's entropy on first use).

        The encoder draws random void fillings once per trial (``void_draws="trial"``, at decision 0), so one
        policy acts in one stream of trials at a time: rooms stepped in turn want a policy each.
        """
        check_number("epsilon", epsilon, low=0.0, high=1.0)
        self.check_observations(obs, info)
        if generator is None:
            if self._generator is None:
                self._generator = torch.Generator(device=self.device)
                self._generator.seed()
            generator = self._generator
        elif not isinstance(generator, torch.Generator):
            raise TypeError(f"generator is a {type(generator).__name__}: must be a torch.Generator (or None)")
        rows = self.rows(obs, info, generator)
        return epsilon_greedy(self.q_values, rows, epsilon, generator).view(obs.shape[0], obs.shape[1])

    def check_observations(self, obs: Any, info: Any) -> None:
        """:func:`check_observations` against this policy's encoder and device."""
        check_observations(obs, info, getattr(self.encoder, "settings", None), self.device)

    def controller(self, epsilon: float = 0.0, generator: torch.Generator | None = None) -> PolicyController:
        """This policy as a controller of the evaluation engine, with a fixed ``epsilon`` and ``generator``."""
        return PolicyController(self, epsilon=epsilon, generator=generator)

    # ------------------------------------------------------------------ checks and files
    def check(self, num_actions: int | None = None) -> None:
        """One-line ``ValueError`` unless the tables are finite float32 ``(P, A, K, U)`` with the encoder's K, P
        matching its per-process quantizers, and U = ``num_actions`` (when given)."""
        q_values = self.q_values
        processes, tables, num_states, actions = q_values.shape
        expected = (processes, tables, self.encoder.num_states, num_actions if num_actions is not None else actions)
        if q_values.dtype != torch.float32 or tuple(q_values.shape) != expected or min(expected) < 1:
            raise ValueError(
                f"tensor q_values is {q_values.dtype} {tuple(q_values.shape)}: must be float32 {expected} "
                "(processes, tables, prototypes, actions)"
            )
        parts = getattr(self.encoder.quantizer, "num_processes", None)  # one quantizer per process, or shared
        if parts is not None and parts != processes:
            raise ValueError(
                f"tensor q_values is {q_values.dtype} {tuple(q_values.shape)} for {processes} processes, and the file "
                f"holds {parts} quantizer(s): must hold one per process"
            )
        if not bool(torch.isfinite(q_values).all()):
            raise ValueError("tensor q_values holds NaN or infinite values: must be finite")
        self.encoder.check()

    def tensors(self) -> dict[str, torch.Tensor]:
        """The tables and the quantizer as named tensors: ``q_values`` and ``quantizer/<key>`` (as files hold them)."""
        return {
            "q_values": self.q_values,
            **{f"{QUANTIZER_PREFIX}/{k}": v for k, v in self.encoder.state_dict().items()},
        }

    def save(self, path: str | Path) -> Path:
        """Write the encoder and the tables, with their metadata, to ``path`` (:func:`write_policy_file`)."""
        return write_policy_file(self, path)

    @classmethod
    def load(cls, path: str | Path, *, device: str | torch.device = "cpu") -> TabularPolicy:
        """Read a policy file of tables written by :meth:`save` (``pedrl-export``; :func:`read_policy_file`).

        Raises:
            CheckpointError: one line naming the file and what is wrong.
        """
        return read_policy_file(path, device=device, learner=cls.learner)


def check_policy_header(meta: Mapping[str, Any]) -> EncoderSettings:
    """The encoder settings of an exported policy file (``meta`` with ``kind`` :data:`POLICY_KIND`), after a one-line
    ``ValueError`` for an unknown ``policy_version`` or missing or bad ``encoder`` settings."""
    if meta.get("policy_version") != POLICY_VERSION:
        version = meta.get("policy_version")
        raise ValueError(f"metadata policy_version={version!r} is unknown: this pedrl reads {POLICY_VERSION}")
    if "encoder" not in meta:
        raise ValueError("metadata encoder is missing: a policy file stores its encoder settings")
    return EncoderSettings.from_metadata(meta["encoder"])


def check_policy_file(meta: Mapping[str, Any], tensors: Mapping[str, torch.Tensor]) -> EncoderSettings:
    """The encoder settings of an exported policy file of tables (:func:`check_policy_header`), after a one-line
    ``ValueError`` for a tensor other than ``q_values`` and ``quantizer/...`` (the tensors themselves are checked by
    :func:`from_tensors`)."""
    settings = check_policy_header(meta)
    _check_table_names(tensors)
    return settings


def _check_table_names(tensors: Mapping[str, torch.Tensor]) -> None:
    for name in set(tensors) - {"q_values"}:
        if not name.startswith(QUANTIZER_PREFIX + "/"):
            raise ValueError(f"tensor {name} is unknown: allowed: q_values, quantizer/...")


def tables_from_file(
    settings: EncoderSettings,
    tensors: Mapping[str, torch.Tensor],
    *,
    num_actions: int | None = None,
    metadata: Mapping[str, Any] | None = None,
) -> TabularPolicy:
    """The reader of a policy file of tables (:data:`POLICY_READERS`): only ``q_values`` and ``quantizer/...``."""
    _check_table_names(tensors)
    return from_tensors(settings, tensors, num_actions=num_actions, metadata=metadata)


def check_observations(obs: Any, info: Any, settings: EncoderSettings | None, device: torch.device) -> None:
    """One-line ``TypeError``/``ValueError`` unless ``obs`` is a float tensor ``(R, N, F)`` on ``device``, of the
    width of ``settings`` (an encoder's; None: any width), and ``info`` the mapping ``RoomEnv`` returns
    (``num_sensed`` ``(R, N)`` and ``decision``, which an encoder reads)."""
    if not isinstance(obs, torch.Tensor):
        raise TypeError(f"obs is a {type(obs).__name__}: must be a torch.Tensor (R, N, F) as RoomEnv returns")
    width = settings.num_features if settings is not None else obs.shape[-1]
    if obs.dim() != 3 or obs.shape[-1] != width or not obs.is_floating_point():
        raise ValueError(
            f"obs is {obs.dtype} {tuple(obs.shape)}: must be float (R, N, {width}), the observations of the room "
            "the policy learned in"
        )
    if obs.device != device:
        raise ValueError(f"obs is on {obs.device}: must be on the policy's device, {device}")
    if not isinstance(info, Mapping):
        raise TypeError(f"info is a {type(info).__name__}: must be the mapping RoomEnv returns")
    if settings is not None and ("num_sensed" not in info or "decision" not in info):
        raise ValueError("info must be the mapping RoomEnv returns (with num_sensed and decision)")
    if "num_sensed" in info and tuple(info["num_sensed"].shape) != tuple(obs.shape[:2]):
        shape, wanted = tuple(info["num_sensed"].shape), tuple(obs.shape[:2])
        raise ValueError(f"info['num_sensed'] is {shape}: must be {wanted}, one per agent")


def offset_ids(base_rows: torch.Tensor, ids: torch.Tensor) -> torch.Tensor:
    """Flat table rows of state ids: ``base_rows (B,)`` (each agent's table's first row) plus ``ids (B,)``, or plus
    each id of the sets ``ids (B, M)`` of a factored table (-1 stays -1, an empty slot)."""
    if ids.ndim == 2:
        return torch.where(ids >= 0, base_rows[:, None] + ids, -1)
    return base_rows + ids


class PolicyController:
    """A :class:`TabularPolicy` with a fixed ``epsilon`` and ``generator``: the evaluation engine's controller
    (``act(env, obs, info)``)."""

    def __init__(
        self, policy: TabularPolicy, *, epsilon: float = 0.0, generator: torch.Generator | None = None
    ) -> None:
        check_number("epsilon", epsilon, low=0.0, high=1.0)
        self.policy = policy
        self.epsilon = float(epsilon)
        self.generator = generator if generator is not None else torch.Generator(device=policy.device)

    def act(self, env: Any, obs: torch.Tensor, info: Mapping[str, Any]) -> torch.Tensor:
        """Actions ``(R, N)`` int64 for observations ``obs (R, N, F)``."""
        return self.policy.act(obs, info, epsilon=self.epsilon, generator=self.generator)


def check_quantizer_tensors(tensors: Mapping[str, torch.Tensor]) -> None:
    """One-line ``ValueError`` for a quantizer tensor (named without the ``quantizer/`` prefix) of an unknown
    name, a wrong dtype, or with NaN or infinite values."""
    for name, tensor in tensors.items():
        leaf = name.rsplit("/", 1)[-1].rsplit(".", 1)[-1]
        dtype = QUANTIZER_DTYPES.get(leaf)
        if dtype is None:
            raise ValueError(f"tensor quantizer/{name} is unknown: allowed names end in {', '.join(QUANTIZER_DTYPES)}")
        if tensor.dtype != dtype:
            raise ValueError(f"tensor quantizer/{name} is {tensor.dtype}: must be {dtype}")
        if tensor.is_floating_point() and not bool(torch.isfinite(tensor).all()):
            raise ValueError(f"tensor quantizer/{name} holds NaN or infinite values: must be finite")


def rebuild_quantizer(tensors: Mapping[str, torch.Tensor]) -> Any:
    """The quantizer of checked ``tensors`` (named without the ``quantizer/`` prefix); one line if they do not
    form one."""
    if not tensors:
        raise ValueError("the quantizer tensors (quantizer/...) are missing")
    check_quantizer_tensors(tensors)
    try:
        return quantizer_from_state_dict(dict(tensors))
    except (KeyError, ValueError, RuntimeError, TypeError, IndexError) as err:
        reason = first_line(err)
        raise ValueError(f"the quantizer tensors do not form a quantizer ({reason})") from None


def from_tensors(
    settings: EncoderSettings,
    tensors: Mapping[str, torch.Tensor],
    *,
    num_actions: int | None = None,
    metadata: Mapping[str, Any] | None = None,
) -> TabularPolicy:
    """A checked policy from a file's tensors (``q_values`` and ``quantizer/...``) and its encoder settings."""
    prefix = QUANTIZER_PREFIX + "/"
    quantizer = rebuild_quantizer({k[len(prefix) :]: v for k, v in tensors.items() if k.startswith(prefix)})
    q_values = tensors.get("q_values")
    if q_values is None:
        raise ValueError("tensor q_values is missing")
    if q_values.ndim != 4:
        raise ValueError(f"tensor q_values is {q_values.dtype} {tuple(q_values.shape)}: must be (P, A, K, U)")
    policy = TabularPolicy(StateEncoder(settings, quantizer), q_values, metadata=metadata)
    policy.check(num_actions)
    return policy


register_learner(TABLE_LEARNER, tables_from_file)
