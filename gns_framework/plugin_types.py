"""The typed records plugin hooks return besides component classes: metrics and commands.

It imports nothing else from gns-framework (nor torch), so the command line can
collect commands, and the registry metrics, without loading any component.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any


@dataclass(frozen=True)
class Metric:
    """One rollout metric, as a plugin's ``gns_metrics`` hook returns it.

    Attributes:
        name: its key in reports and ``evaluation_*`` tracked metrics; a family's
            pattern (``mse_{h}``, ``mse_full[<material>]``) when ``function`` returns several.
        unit: unit, a comma, then what it measures (``"L, RMS error of ..."``), shown in reports.
        function: the value for a :class:`~gns_framework.evaluation.metrics.RolloutPair`:
            a (B,) tensor, None when it cannot be taken (missing), or
            ``{name: (B,) tensor or None}`` for a family.
        pairwise: compares particle i of the prediction with particle i of the truth
            (position errors). Such a metric sees the raw prediction (a non-finite
            position gives an inf error by itself) and must give None when
            ``pair.same_particles`` is False. Any other metric compares the clouds; it
            sees finite stand-in positions, and is inf wherever the rollout diverged.
        validation: also measured while training, on the validation rollouts, as
            ``valid_rollout_<validation>`` (mean over the rollouts where it can be
            taken) and ``valid_rollout_<validation>_worst`` (the largest), either of which
            ``training.best_metric`` may then choose; None: evaluation only.
            A single metric only, not a family.
    """

    name: str
    unit: str
    function: Callable[[Any], Any | Mapping[str, Any] | None]
    pairwise: bool = False
    validation: str | None = None

    @property
    def tracked_as(self) -> str | None:
        """``valid_rollout_<validation>``, its name in training's metrics and ``training.best_metric``; None if
        untracked."""
        return None if self.validation is None else f"valid_rollout_{self.validation}"


def worst_of(tracked: str) -> str:
    """The name under which the largest of a tracked error over the validation rollouts is recorded."""
    return f"{tracked}_worst"


@dataclass(frozen=True)
class Command:
    """A ``gns`` subcommand, as a plugin's ``gns_commands`` hook returns it.

    Attributes:
        name: the subcommand (``gns <name>``).
        help: its one-line help, shown by ``gns --help``.
        module: dotted name of the module that implements it: ``add_arguments(parser)``
            and ``run(args) -> int`` (the exit status). It is imported only when the
            command runs or its own ``--help`` is asked for, so ``gns --help`` stays fast.
    """

    name: str
    help: str
    module: str
