"""What a granular deposit and the rollout that made it say about themselves, without any simulator.

A learned sand model is furthest off where a front ran a long way and ended near a block, a hump or a wall: a
little more or less momentum decides whether it reaches, climbs or stops. These are the numbers of one rollout
that say so, read from the scene and the learned positions alone (``benchmarks/front_warning.py`` measured each
as a warning; :mod:`.deposit_warning` combines them).

Physics. The deposit's extent is set by its two outer fronts. A front that hardly moved, or that ran into a wall,
is placed by the scene (the column's edge, the wall). A front that ran far is placed by the flow, and an error of
the runout is then most of the extent's: with a relative runout error e, the extent is off by about e times the
front's *run share* (its run over the final extent). The *energy ratio* compares the potential energy the sand
released with the work Coulomb friction does along its horizontal path: a deposit at rest has dissipated all it
released, and a front that stopped short of where that energy would carry it raises the ratio.

Lengths are in the dataset's unit (m for the sand scenes); gaps and front motion in particle spacings.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from ..data.particle_spacing import particle_spacing

AT_WALL = 1.0
"""Particle spacings from a wall within which a front is held by it (its place is the wall's)."""
TAIL = 0.1
"""Share of the rollout's last frames whose motion says whether the deposit has stopped."""


@dataclasses.dataclass(frozen=True)
class Front:
    """One outer front of a deposit (the leftmost or rightmost granular particle at the last frame).

    Attributes:
        side: ``left`` or ``right``.
        run: distance the front travelled from the sand's starting edge on its side, L.
        share: ``run`` over the deposit's final extent (0-1).
        gap: particle spacings from the front to the nearest obstacle particle ahead of it (0: on it) or the wall
            ahead, whichever is closer.
        at_wall: whether the front ends within ``AT_WALL`` spacings of the wall ahead.
        tail: particle spacings the front moved over the last ``TAIL`` of the frames (below 1: stopped).
    """

    side: str
    run: float
    share: float
    gap: float
    at_wall: bool
    tail: float


def spacing(start: np.ndarray) -> float:
    """The particle spacing, L: the median distance from a particle of ``start`` (N, d) to its nearest neighbour,
    over every particle (the warning was fitted on that, not on a subset)."""
    return particle_spacing(start, max_queries=len(start))


def fronts(path: np.ndarray, start: np.ndarray, obstacle: np.ndarray, bounds: np.ndarray, h: float) -> list[Front]:
    """The two outer fronts along the first axis of the sand ``path`` (S, N, d) from ``start`` (N, d), among
    ``obstacle`` particles (M, d) and the walls ``bounds`` (d, 2), with particle spacing ``h``, L."""
    extent = np.ptp(path[-1, :, 0])
    tail = max(1, round(TAIL * len(path)))
    out = []
    for side, ahead, edge, wall in (
        ("left", -1.0, np.min, bounds[0, 0]),
        ("right", 1.0, np.max, bounds[0, 1]),
    ):
        series = edge(path[:, :, 0], axis=1)
        x = series[-1]
        run = abs(x - edge(start[:, 0]))
        # Obstacle particles ahead of the front, or under it (within a spacing behind): 0 when it is on one.
        reach = ahead * (obstacle[:, 0] - x)
        to_obstacle = max(reach[reach > -h].min(initial=np.inf), 0.0)
        to_wall = ahead * (wall - x)
        out.append(
            Front(
                side=side,
                run=float(run),
                share=float(run / extent) if extent > 0 else 0.0,
                gap=float(min(to_obstacle, to_wall) / h),
                at_wall=bool(to_wall <= AT_WALL * h),
                tail=float(abs(x - series[-1 - tail]) / h),
            )
        )
    return out


def columns(start: np.ndarray, friction: np.ndarray, gap: float) -> list[np.ndarray]:
    """Indices of each column of sand at the start: runs along the first axis split where neighbours are more than
    ``gap`` apart, L, or their friction changes (two columns side by side)."""
    order = np.argsort(start[:, 0], kind="stable")
    x, phi = start[order, 0], friction[order]
    cuts = np.flatnonzero((np.diff(x) > gap) | (np.abs(np.diff(phi)) > 1e-6)) + 1
    return np.split(order, cuts)


def energy_ratio(start: np.ndarray, final: np.ndarray, friction: np.ndarray) -> float:
    """Potential energy the sand released over the work Coulomb friction does along its horizontal displacement:
    sum of the height drops over the sum of tan(phi) |dx| (1 for a rigid block sliding to rest; a collapse,
    whose inner particles fall more than they travel, is above 1). NaN when nothing moved sideways. The last axis
    is up."""
    work = (friction * np.abs(final[:, 0] - start[:, 0])).sum()
    return float((start[:, -1] - final[:, -1]).sum() / work) if work > 0 else float("nan")


def other_signals(
    path: np.ndarray, start: np.ndarray, friction: np.ndarray, obstacle: np.ndarray, bounds: np.ndarray, h: float
) -> dict[str, float]:
    """The scene's and the deposit's signals besides the fronts, of the sand ``path`` (S, N, d) from ``start``
    (N, d), of per-particle tan(phi) ``friction`` (N,), among ``obstacle`` particles (M, d) and walls ``bounds``
    (d, 2), with particle spacing ``h``, L.

    ``runout_ratio``: the largest column's final over starting width; ``aspect`` and ``tan_phi``: the tallest
    column's height over width and its friction; ``end_energy``: the kinetic energy of the last ``TAIL`` of the
    frames over the peak; ``touching``: the share of particles within a spacing of a wall or an obstacle at the
    end; ``energy_ratio``: see :func:`energy_ratio`.
    """
    from scipy.spatial import cKDTree

    final = path[-1]
    ratios, aspects, tan_phis = [], [], []
    for index in columns(start, friction, 2 * h):
        width = np.ptp(start[index, 0]) + h
        ratios.append((np.ptp(final[index, 0]) + h) / width)
        aspects.append((start[index, -1].max() - bounds[-1, 0] + h / 2) / width)
        tan_phis.append(float(friction[index[0]]))
    tallest = int(np.argmax(aspects))
    step = np.diff(np.concatenate([start[None], path]), axis=0)
    energy = (step**2).sum(axis=2).mean(axis=1)
    tail = max(1, round(TAIL * len(path)))
    touching = (final[:, 0] - bounds[0, 0] < h) | (bounds[0, 1] - final[:, 0] < h)
    if len(obstacle):
        touching |= cKDTree(obstacle).query(final, k=1)[0] < 1.5 * h
    signals = {
        "runout_ratio": max(ratios),
        "aspect": aspects[tallest],
        "tan_phi": tan_phis[tallest],
        "aspect_over_tan_phi": aspects[tallest] / tan_phis[tallest] if tan_phis[tallest] > 0 else float("inf"),
        "end_energy": energy[-tail:].mean() / energy.max() if energy.max() > 0 else 0.0,
        "touching": touching.mean(),
        "energy_ratio": energy_ratio(start, final, friction),
    }
    return {name: float(value) for name, value in signals.items()}


@dataclasses.dataclass(frozen=True)
class DepositSignals:
    """Everything :mod:`.deposit_warning` reads of one rollout: its two fronts and the other signals (with
    ``held``, the particles a wall held, and ``sand_particles``)."""

    fronts: list[Front]
    signals: dict[str, float]

    def leading(self) -> Front:
        """The front that ran the larger share of the extent."""
        return max(self.fronts, key=lambda f: f.share)


def deposit_signals(
    path: np.ndarray,
    start: np.ndarray,
    friction: np.ndarray,
    obstacle: np.ndarray,
    bounds: np.ndarray,
    held: int = 0,
) -> DepositSignals:
    """The signals of a sand rollout ``path`` (S, N, d) from ``start`` (N, d), tan(phi) ``friction`` (N,), among
    fixed ``obstacle`` particles (M, d) in the box ``bounds`` (d, 2), L; ``held``: particles a wall held."""
    h = spacing(start)
    signals = other_signals(path, start, friction, obstacle, bounds, h)
    return DepositSignals(
        fronts(path, start, obstacle, bounds, h), {**signals, "held": float(held), "sand_particles": float(len(start))}
    )
