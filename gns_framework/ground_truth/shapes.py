"""Geometry of rotated bodies, polygons and inclined planes: the particles that stand for them.

Rotations turn the x-y plane counter-clockwise (about the z axis in 3D, y up),
by angles in degrees. The simulator applies the same shapes as signed-distance
boundary conditions; here they become lattice particles, so a dataset records
what the learned model must see.
"""

from __future__ import annotations

import math

import numpy as np


def rotate_xy(points: np.ndarray, angle: float, centre: np.ndarray) -> np.ndarray:
    """(n, d) ``points`` turned by ``angle`` degrees about ``centre`` (d,) in the x-y plane."""
    if angle == 0.0:
        return points
    c, s = math.cos(math.radians(angle)), math.sin(math.radians(angle))
    rel = points - centre
    turned = rel.copy()
    turned[:, 0] = c * rel[:, 0] - s * rel[:, 1]
    turned[:, 1] = s * rel[:, 0] + c * rel[:, 1]
    return turned + centre


def counter_clockwise(vertices: np.ndarray) -> np.ndarray:
    """(n, 2) polygon corners in counter-clockwise order (positive shoelace area)."""
    x, y = vertices[:, 0], vertices[:, 1]
    area = 0.5 * np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y)
    return vertices if area > 0 else vertices[::-1].copy()


def polygon_contains(points: np.ndarray, vertices: np.ndarray) -> np.ndarray:
    """(n,) whether each point's x-y lies inside the polygon (even-odd crossing rule)."""
    x, y = points[:, 0:1], points[:, 1:2]
    a, b = vertices, np.roll(vertices, -1, axis=0)
    straddles = (a[:, 1] > y) != (b[:, 1] > y)
    with np.errstate(divide="ignore", invalid="ignore"):
        crossing = a[:, 0] + (y - a[:, 1]) / (b[:, 1] - a[:, 1]) * (b[:, 0] - a[:, 0])
    return (np.sum(straddles & (x < crossing), axis=1) % 2) == 1


def polygon_lattice(vertices: np.ndarray, spacing: float) -> np.ndarray:
    """(n, 2) lattice points at ``spacing`` inside the polygon, anchored at the lower corner of its bounding box."""
    lower, upper = vertices.min(axis=0), vertices.max(axis=0)
    counts = np.maximum(1, np.round((upper - lower) / spacing).astype(int))
    axes = [lower[a] + (np.arange(counts[a]) + 0.5) * spacing for a in range(2)]
    points = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 2)
    return points[polygon_contains(points, vertices)]


def plane_layer(point: np.ndarray, angle: float, bounds: np.ndarray, spacing: float, layers: int) -> np.ndarray:
    """(n, d) particles of an inclined plane: ``layers`` rows under its surface, within ``bounds`` (d, 2).

    The surface passes through ``point`` and rises at ``angle`` degrees along +x;
    rows run parallel to it, the first half a spacing below it.
    """
    d = len(point)
    c, s = math.cos(math.radians(angle)), math.sin(math.radians(angle))
    along, normal = np.array([c, s]), np.array([-s, c])
    reach = float(np.linalg.norm(bounds[:2, 1] - bounds[:2, 0])) + float(np.abs(point[:2] - bounds[:2, 0]).max())
    t = np.arange(-reach, reach, spacing) + 0.5 * spacing
    rows = [point[:2] + t[:, None] * along - (j + 0.5) * spacing * normal for j in range(layers)]
    xy = np.concatenate(rows)
    if d == 3:
        z = bounds[2, 0] + (np.arange(max(1, round((bounds[2, 1] - bounds[2, 0]) / spacing))) + 0.5) * spacing
        xy = np.concatenate([np.repeat(xy, len(z), axis=0), np.tile(z, len(xy))[:, None]], axis=1)
    return xy[inside(xy, bounds)]


def inside(points: np.ndarray, bounds: np.ndarray) -> np.ndarray:
    """(n,) whether each point lies within ``bounds`` (d, 2), walls included."""
    return np.all((points >= bounds[:, 0]) & (points <= bounds[:, 1]), axis=1)
