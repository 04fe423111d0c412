"""Fitting a phase's quantizers on gathered states: feature weights, subsampling, one fit per process or one shared.

The trainers call :func:`fit_quantizers` with their own ``fit_one`` (a plain :class:`pedrl.vq.Quantizer` for VQQL and
IT-VQQL, IN-VQQL's union grown by one part); everything else about the fit is here.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Callable, Sequence
from typing import Any, Final

import torch

from pedrl.algos.budget import agents_text
from pedrl.algos.phase import Phase
from pedrl.notices import warn
from pedrl.trial.rollout import Gathered
from pedrl.vq import FactoredQuantizer, ProcessQuantizers, Quantizer
from pedrl.vq.encoder import EncoderSettings
from pedrl.vq.settings import VQSettings

KMEANS_SHRINK: Final = "k-means: the data has only"
"""Start of k-means' own warning when it keeps fewer prototypes; the trainers say it once, in their words."""
FitOne = Callable[[torch.Tensor, torch.Tensor, Any, "int | None"], tuple[Any, float]]
"""``fit_one(states (M, F), num_sensed (M,), previous part or None, num_prototypes or None) -> (quantizer,
distortion)``: one quantizer fitted on one process's (or all processes') states."""


def neighbour_weights(value: float | Sequence[float], num_neighbours: int) -> list[float]:
    """``vq.weight_neighbours`` as one weight per neighbour rank, validated (one line naming the value)."""
    weights = [value] * num_neighbours if isinstance(value, int | float) else list(value)
    allowed = f"a number > 0 or a list of {num_neighbours} numbers > 0 (one per neighbour, nearest first)"
    if len(weights) != num_neighbours or not all(
        isinstance(w, int | float) and not isinstance(w, bool) and math.isfinite(w) and w > 0 for w in weights
    ):
        raise ValueError(f"vq.weight_neighbours={value!r} is invalid: must be {allowed}")
    return [float(w) for w in weights]


def feature_weights(
    vq: VQSettings,
    num_neighbours: int,
    num_features: int,
    device: torch.device,
    feature_index: torch.Tensor | None = None,
) -> torch.Tensor:
    """Per-feature weights ``(F,)`` float64 (or of the features ``feature_index`` selects) from the ``vq``
    settings: the agent's own 3 features, then 3 per neighbour rank, then the walls."""
    own, neighbours = 3, 3 * num_neighbours
    weights = torch.full((num_features,), vq.weight_walls, dtype=torch.float64, device=device)
    weights[:own] = vq.weight_own
    per_rank = torch.as_tensor(neighbour_weights(vq.weight_neighbours, num_neighbours), dtype=torch.float64)
    weights[own : own + neighbours] = per_rank.repeat_interleave(3).to(device)
    return weights if feature_index is None else weights[feature_index]


def fit_plain_quantizer(
    states: torch.Tensor,
    vq: VQSettings,
    weights: torch.Tensor,
    generator: torch.Generator,
    num_prototypes: int | None = None,
) -> tuple[Quantizer, float]:
    """One :class:`pedrl.vq.Quantizer` fitted on ``states (M, F)`` with the ``vq`` settings and per-feature
    ``weights (F,)``; ``num_prototypes`` is K (None: ``vq.num_prototypes``). Returns it and its final distortion."""
    quantizer, result = Quantizer.fit(
        states,
        vq.num_prototypes if num_prototypes is None else num_prototypes,
        generator=generator,
        feature_weights=weights,
        **vq.kmeans_arguments(),
    )
    return quantizer, float(result.distortion[-1])


def fit_factored_quantizer(
    states: torch.Tensor,
    num_sensed: torch.Tensor,
    vq: VQSettings,
    settings: EncoderSettings,
    generator: torch.Generator,
) -> tuple[FactoredQuantizer, float]:
    """A :class:`pedrl.vq.FactoredQuantizer` of ``vq.factors`` fitted on prepared ``states (M, F)`` with
    ``num_sensed (M,)`` neighbours (each factor on its slots, at most ``vq.max_states`` rows each), and the mean of
    its factors' distortions. A factor of fewer distinct values than its K keeps fewer prototypes: that is the data,
    not a shortfall to report."""
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message=KMEANS_SHRINK, category=UserWarning)
        return FactoredQuantizer.fit(
            states,
            num_sensed,
            vq.factor_specs,
            num_neighbours=settings.num_neighbours,
            num_walls=settings.num_walls,
            max_states=vq.max_states,
            generator=generator,
            **vq.kmeans_arguments(),
        )


def factored_problem(part: Any, vq: VQSettings) -> str | None:
    """Why ``part`` (a checkpoint's quantizer) cannot be the factored quantizer of ``vq.factors``, or None."""
    sizes = {spec.name: spec.num_prototypes for spec in vq.factor_specs}
    if not isinstance(part, FactoredQuantizer) or set(part.parts) != set(sizes):
        return f"is a {type(part).__name__}: must be a FactoredQuantizer of {', '.join(sizes)}"
    for name, quantizer in part.parts.items():
        if quantizer.num_prototypes > sizes[name]:
            return f"has {quantizer.num_prototypes} {name} prototypes: must have at most {sizes[name]}"
    return None


def subsample(
    states: torch.Tensor, num_sensed: torch.Tensor, max_states: int, generator: torch.Generator
) -> tuple[torch.Tensor, torch.Tensor]:
    """At most ``max_states`` of the states (a uniform random subset), with their neighbour counts."""
    if states.shape[0] <= max_states:
        return states, num_sensed
    keep = torch.randperm(states.shape[0], generator=generator, device=states.device)[:max_states]
    return states[keep], num_sensed[keep]


def fit_quantizers(
    phase: Phase,
    gathered: Gathered,
    previous: Any | None,
    fit_one: FitOne,
    *,
    vq: VQSettings,
    processes: int,
    kept: int,
    generator: torch.Generator,
) -> tuple[Any, float]:
    """This phase's quantizer: one :class:`pedrl.vq.ProcessQuantizers` part per learning process, each fitted
    on the states its own rooms visited (``vq.per_process``), or one shared by all processes.

    Each fit sees at most ``vq.max_states`` states (a uniform random subset). When the states of some process
    hold fewer distinct states than ``vq.num_prototypes``, k-means keeps fewer prototypes there, and every
    process is fitted again with that smallest count (the processes' Q tables stack, so they share K), with a
    one-line warning and no error. ``kept`` prototypes of ``previous`` stay in every part besides those the fit
    adds (IN-VQQL's union). Returns the quantizer and the mean distortion of its parts.
    """
    states, num_sensed, process = gathered.states, gathered.num_sensed, gathered.process

    def fit(mine: torch.Tensor | None, part: Any | None, count: int | None = None) -> tuple[Any, float]:
        own = (states, num_sensed) if mine is None else (states[mine], num_sensed[mine])
        return fit_one(*subsample(*own, vq.max_states, generator), part, count)

    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message=KMEANS_SHRINK, category=UserWarning)  # said once below
        if not vq.per_process:
            quantizer, distortion = fit(None, previous)
            report_shrink(phase, quantizer.num_prototypes - kept, vq.table_states, None)
            return quantizer, distortion
        fits = [fit(process == index, _part(previous, index)) for index in range(processes)]
        sizes = [part.num_prototypes for part, _ in fits]
        smallest = min(sizes)
        for index, size in enumerate(sizes):
            if size > smallest:
                fits[index] = fit(process == index, _part(previous, index), smallest - kept)
    report_shrink(phase, smallest - kept, vq.num_prototypes, sizes.index(smallest))
    return ProcessQuantizers([part for part, _ in fits]), sum(d for _, d in fits) / len(fits)


def _part(previous: Any | None, index: int) -> Any | None:
    return previous.parts[index] if previous is not None else None


def report_shrink(phase: Phase, fitted: int, wanted: int, process: int | None) -> None:
    """One line when the quantizer of ``phase`` got ``fitted < wanted`` prototypes, because the states gathered
    by ``process`` (None: by all, for a shared quantizer) hold no more distinct ones."""
    if fitted >= wanted:
        return
    whose = "the gathered states" if process is None else f"the states gathered by process {process}"
    every = "the quantizer" if process is None else "every process's quantizer"
    warn(
        f"phase {phase.index} ({agents_text(phase.num_agents)}): {whose} hold only {fitted} distinct states for "
        f"vq.num_prototypes={wanted}; {every} uses K = {fitted} in this phase (raise algo.gather_trials "
        f"to keep {wanted})"
    )
