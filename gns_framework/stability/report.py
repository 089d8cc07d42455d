"""The stability report: every stiff and extreme case with its outcome and figures (``gns stability``).

Each case is a function returning :class:`Row` objects; :func:`run_report` runs
them all (well under a minute on one CPU core) and :func:`format_row` prints them.
Each row says whether its outcome is a failure: an outcome is judged against what
the case must show (a symplectic integrator must keep the energy bounded, explicit
Euler is expected to gain it), so ``gns stability`` exits non-zero on any failing row.

What each integrator must show comes from its own attributes (``symplectic``,
``stability_bound``); every installed integrator with a physical form (``advance``)
and every installed processor is measured, not a list of names.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator
from dataclasses import dataclass

import numpy as np
import torch

from ..config.recipe import ModelSpec
from ..data.trajectory import Trajectory
from ..errors import RolloutDiverged
from ..model.rollout import rollout
from ..model.rollout_guard import RolloutGuard
from ..plugins import Registry
from .extreme import CASES, check_finite, tiny_simulator
from .measure import (
    collide,
    collision_dt_limit,
    energy_record,
    explicit_euler_horizon_limit,
    stability_limit,
)
from .problems import RepulsiveCollision, SpringChain

CHAIN = SpringChain(num_masses=32, stiffness=1e6)
"""The stiff chain of the report: 32 unit masses, k = 1e6 (omega_max = 2000 rad per unit time)."""
COLLISION = RepulsiveCollision(closest_approach=0.5)
"""The near-collision of the report: turning at half sigma, 4096 epsilon deep into the r^-12 wall."""
LIMIT_STEPS, LIMIT_GROWTH = 2000, 1e8
COLLISION_ENERGY_ERROR = 0.01
DRIFT_STEPS = 10_000
REFERENCE_PROCESSOR = ModelSpec().processor.name
"""The processor of the extreme-input cases in both dimensions; every other installed one is run in 2D."""


def physical_integrators(registry: Registry) -> list[str]:
    """Installed integrators with a physical form (``advance``): symplectic ones first, then by name."""
    physical = [e for e in registry.entries("integrator") if hasattr(e.cls, "advance")]
    return [e.name for e in sorted(physical, key=lambda e: (not e.cls.symplectic, e.name))]


def other_processors(registry: Registry) -> list[str]:
    return [name for name in registry.names("processor") if name != REFERENCE_PROCESSOR]


@dataclass(frozen=True)
class Row:
    group: str
    case: str
    outcome: str
    figures: str
    failing: bool = False
    """The outcome is not what the case must show (printed with a FAIL mark; gns stability exits 1)."""


def chain_limits(registry: Registry) -> Iterator[Row]:
    for name in physical_integrators(registry):
        integrator = registry.get("integrator", name)
        advance = integrator.advance
        if not integrator.stability_bound:
            # No bound: search below the symplectic one (omega dt = 2), where a stable integrator would hold.
            ceiling = 2 / CHAIN.highest_frequency
            expected = explicit_euler_horizon_limit(CHAIN, LIMIT_STEPS, LIMIT_GROWTH)
            found = stability_limit(advance, CHAIN, 1e-4 * ceiling, ceiling, LIMIT_STEPS, LIMIT_GROWTH)
            failing = found.dt < expected
            outcome = "below the one-mode bound" if failing else "unstable for every dt"
            figures = (
                f"no limit; {LIMIT_GROWTH:.0e}x energy in {LIMIT_STEPS} steps at dt = {found.dt:.4g} "
                f"(omega_max dt = {found.dt * CHAIN.highest_frequency:.3g}; one-mode bound {expected:.4g})"
            )
        else:
            theory = integrator.stability_bound / CHAIN.highest_frequency
            found = stability_limit(advance, CHAIN, 1e-3 * theory, 2 * theory, LIMIT_STEPS, LIMIT_GROWTH)
            error = found.dt / theory - 1
            failing = not abs(error) < 1e-4
            outcome = "limit differs from theory" if failing else "limit as theory"
            figures = (
                f"dt_max = {found.dt:.6g} (theory {integrator.stability_bound:g}/omega_max = {theory:.6g}, "
                f"{error:+.1e})"
            )
        yield Row("spring chain N=32 k=1e6: dt limit", name, outcome, figures, failing)


def chain_drift(registry: Registry) -> Iterator[Row]:
    for omega_dt in (0.1, 1.0):
        dt = omega_dt / CHAIN.highest_frequency
        for name in physical_integrators(registry):
            integrator = registry.get("integrator", name)
            record = energy_record(integrator.advance, CHAIN, dt, DRIFT_STEPS)
            if not record.finite:
                bounded = False
                outcome, figures = "diverged", f"energy non-finite at step {record.first_non_finite_step}"
            else:
                bounded = abs(record.drift) < 0.1 * max(record.max_error, 1e-12) + 1e-9
                outcome = "bounded, no drift" if bounded else "energy grows"
                figures = f"max |dE/E0| = {record.max_error:.3g}, drift {record.drift:+.2g}"
            # Below its stability bound a symplectic scheme must keep the energy bounded; explicit Euler gains it.
            failing = integrator.symplectic and omega_dt < (integrator.stability_bound or 0) and not bounded
            yield Row(f"spring chain: {DRIFT_STEPS} steps, omega_max dt = {omega_dt}", name, outcome, figures, failing)


def near_collision(registry: Registry) -> Iterator[Row]:
    omega = COLLISION.contact_frequency
    for name in physical_integrators(registry):
        integrator = registry.get("integrator", name)
        advance = integrator.advance
        limit = collision_dt_limit(advance, COLLISION)
        fine = collide(advance, COLLISION, 0.1 / omega)
        coarse = collide(advance, COLLISION, 30 / omega)
        outcome = "tunnels at 30/omega" if coarse.passed_through else "no tunnelling at 30/omega"
        figures = (
            f"1% energy error at dt = {limit * omega:.3g}/omega_contact; |dE/E0| = {fine.energy_error:.2g} at 0.1/omega"
        )
        # Resolving the contact (dt = 0.1/omega), a symplectic scheme must hold the energy within 1%.
        failing = integrator.symplectic and not fine.energy_error < COLLISION_ENERGY_ERROR
        if failing:
            outcome = f"energy error over {COLLISION_ENERGY_ERROR:.0%} at 0.1/omega"
        yield Row("near-collision r^-12, r_min = sigma/2", name, outcome, figures, failing)
    for entry in registry.entries("integrator"):
        if not hasattr(entry.cls, "advance"):
            yield Row(
                "near-collision r^-12, r_min = sigma/2",
                entry.name,
                "n/a",
                f"no physical form: it needs a {entry.cls.predicts} law, not a force law",
            )


def _extreme_row(simulator, case: str, dim: int, dtype: torch.dtype, label: str) -> Row:
    outcome = check_finite(simulator, CASES[case](dim, torch.Generator().manual_seed(0)), dtype)
    result = "finite" if outcome.finite else "NaN/Inf in " + ", ".join(outcome.failures)
    figures = (
        f"{outcome.num_edges} edges, up to {outcome.max_neighbours} neighbours, "
        f"max |prediction| {outcome.max_abs_prediction:.3g}"
    )
    return Row(
        f"learned simulator, {label}",
        f"{case}, {dim}D, {str(dtype).removeprefix('torch.')}",
        result,
        figures,
        failing=not outcome.finite,
    )


def extreme_inputs(registry: Registry) -> Iterator[Row]:
    for dim in (2, 3):
        simulator = tiny_simulator(registry, dim)
        zero_std = tiny_simulator(registry, dim, zero_std=True)
        for dtype in (torch.float32, torch.bfloat16):
            for case in CASES:
                yield _extreme_row(simulator, case, dim, dtype, REFERENCE_PROCESSOR)
            yield _extreme_row(zero_std, "coincident particles", dim, dtype, f"{REFERENCE_PROCESSOR}, zero std")
    for processor in other_processors(registry):
        simulator = tiny_simulator(registry, 2, processor)
        rows = [
            _extreme_row(simulator, case, 2, dtype, processor)
            for case in CASES
            for dtype in (torch.float32, torch.bfloat16)
        ]
        failures = [row.case for row in rows if row.failing]
        yield Row(
            f"learned simulator, {processor}",
            "every case, 2D, float32 and bfloat16",
            f"{len(rows) - len(failures)}/{len(rows)} finite",
            "failed: " + "; ".join(failures) if failures else "",
            failing=bool(failures),
        )


def _resting_trajectory(dim: int) -> Trajectory:
    grid = np.stack(np.meshgrid(*[np.linspace(0.3, 0.7, 3)] * dim, indexing="ij"), -1).reshape(-1, dim)
    position = np.repeat(grid[None].astype(np.float32), 12, axis=0)
    return Trajectory(position, np.full(len(grid), 5, dtype=np.int64), key="resting")


def rollout_guard(registry: Registry) -> Iterator[Row]:
    """A model sabotaged to predict NaN, and one that flings particles out, under stop and clamp."""
    trajectory = _resting_trajectory(2)
    sabotage: dict[str, Callable] = {
        "NaN prediction": lambda sim: sim.output_stats.mean.fill_(math.nan),
        "particles flung out": lambda sim: sim.output_stats.mean.fill_(0.5),
    }
    for cause, apply in sabotage.items():
        for mode in ("stop", "clamp"):
            simulator = tiny_simulator(registry, 2)
            apply(simulator)
            guard = RolloutGuard(simulator.setup, margin=0.1, on_violation=mode)
            try:
                result = rollout(simulator, trajectory, steps=5, guard=guard)
            except RolloutDiverged as exc:
                yield Row(
                    "rollout guard (margin 0.1)",
                    f"{cause}, {mode}",
                    f"stopped at step {exc.step}",
                    f"{len(exc.particles)} particle(s) named: {exc.cause}",
                    failing=mode != "stop",
                )
                continue
            finite = bool(np.isfinite(result.predicted).all())
            first = result.guard_violations[0] if result.guard_violations else None
            outcome = f"clamped {len(result.guard_violations)}x, output finite" if finite else "non-finite output"
            if mode == "stop":
                outcome = "not stopped; " + outcome
            figures = first.describe() if first else "no violation detected"
            # Both sabotages break the guard's limits at the first step: it must stop, or clamp to finite output.
            failing = mode == "stop" or not finite or first is None
            yield Row("rollout guard (margin 0.1)", f"{cause}, {mode}", outcome, figures, failing)


SECTIONS: tuple[Callable[[Registry], Iterator[Row]], ...] = (
    chain_limits,
    chain_drift,
    near_collision,
    extreme_inputs,
    rollout_guard,
)


def run_report(registry: Registry, sections=SECTIONS) -> Iterator[Row]:
    """Every row of every section, as it is measured."""
    for section in sections:
        yield from section(registry)


def format_row(row: Row, widths: tuple[int, int, int] = (48, 42, 28)) -> str:
    outcome = f"FAIL: {row.outcome}" if row.failing else row.outcome
    return f"{row.group:<{widths[0]}} {row.case:<{widths[1]}} {outcome:<{widths[2]}} {row.figures}"
