"""The least distance between two sets of axis-aligned boxes, exact, in O((n + m) log) time.

:func:`raytrace.solver.sbr.return_lengths` bounds how far a ray must still travel in a zone
before it can turn towards a receiver by the least distance between the bounding boxes of two
sets of faces (a zone's exit faces and its other faces). On a 1 M-triangle body those sets
pair up ~5e10 times, so the distance is found by a dual-tree search: each set is sorted along
a Morton curve of its box centres and cut in halves recursively (an implicit binary tree whose
node boxes bound their ranges), and pairs of nodes are visited from a stack, nearer halves
first, skipping every pair whose node boxes are no closer than the least distance found so
far (no pair of boxes inside can be closer than their nodes). Leaves of :data:`LEAF` boxes are
compared pair by pair, with the same formula as a test of every pair
(``sqrt(sum(max(lo_b - hi_a, lo_a - hi_b, 0)^2))``), so the result is that test's minimum bit
for bit.
"""

from __future__ import annotations

import math

import numpy as np

from raytrace.engine.jit import kernel

#: Boxes per leaf of the implicit trees.
LEAF = 8


def _morton_order(lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """Indices of the boxes along a Morton (Z-order) curve of their centres (21 bits an axis)."""
    c = 0.5 * (lo + hi)
    span = np.maximum(c.max(axis=0) - c.min(axis=0), 1e-300)
    q = np.clip(((c - c.min(axis=0)) / span * ((1 << 21) - 1)).astype(np.int64), 0, (1 << 21) - 1)
    code = np.zeros(len(c), np.int64)
    for bit in range(21):
        for axis in range(3):
            code |= ((q[:, axis] >> bit) & 1) << (3 * bit + axis)
    return np.argsort(code, kind="stable")


@kernel
def _node_boxes(lo, hi):
    """Bounds of every node of the implicit tree over ``n`` sorted boxes: node k covers
    ``[start, end)``, its children ``2k + 1`` and ``2k + 2`` the halves (cut at the middle),
    down to :data:`LEAF` boxes; returns the node count and the (nodes, 6) bounds, start, end."""
    n = lo.shape[0]
    size = 1
    while size * LEAF < n:
        size *= 2
    nodes = 2 * size - 1
    box = np.empty((nodes, 6))
    start = np.zeros(nodes, np.int64)
    end = np.zeros(nodes, np.int64)
    start[0], end[0] = 0, n
    for k in range(nodes):  # ranges top-down (a parent's index is below its children's)
        if 2 * k + 2 < nodes:
            mid = (start[k] + end[k]) // 2
            start[2 * k + 1], end[2 * k + 1] = start[k], mid
            start[2 * k + 2], end[2 * k + 2] = mid, end[k]
    for k in range(nodes - 1, -1, -1):  # bounds bottom-up
        for q in range(3):
            box[k, q] = np.inf
            box[k, 3 + q] = -np.inf
        if 2 * k + 2 < nodes:
            for c in (2 * k + 1, 2 * k + 2):
                for q in range(3):
                    box[k, q] = min(box[k, q], box[c, q])
                    box[k, 3 + q] = max(box[k, 3 + q], box[c, 3 + q])
        else:
            for i in range(start[k], end[k]):
                for q in range(3):
                    box[k, q] = min(box[k, q], lo[i, q])
                    box[k, 3 + q] = max(box[k, 3 + q], hi[i, q])
    return box, start, end


@kernel
def _gap2(ax0, ay0, az0, ax1, ay1, az1, bx0, by0, bz0, bx1, by1, bz1):
    """Squared distance between two boxes (0 where they overlap)."""
    dx = max(max(bx0 - ax1, ax0 - bx1), 0.0)
    dy = max(max(by0 - ay1, ay0 - by1), 0.0)
    dz = max(max(bz0 - az1, az0 - bz1), 0.0)
    return dx * dx + dy * dy + dz * dz


@kernel
def _least_gap(lo_a, hi_a, box_a, start_a, end_a, lo_b, hi_b, box_b, start_b, end_b):
    """The dual-tree search of the module doc over the sorted boxes and their node bounds."""
    nodes_a, nodes_b = box_a.shape[0], box_b.shape[0]
    best = np.inf  # the least distance found (not squared: the pair test's own numbers)
    stack = np.empty((4096, 2), np.int64)
    stack[0, 0], stack[0, 1] = 0, 0
    top = 1
    while top > 0:
        top -= 1
        i, j = stack[top, 0], stack[top, 1]
        ba, bb = box_a[i], box_b[j]
        if math.sqrt(_gap2(ba[0], ba[1], ba[2], ba[3], ba[4], ba[5], bb[0], bb[1], bb[2], bb[3], bb[4], bb[5])) >= best:
            continue
        leaf_a, leaf_b = 2 * i + 2 >= nodes_a, 2 * j + 2 >= nodes_b
        if leaf_a and leaf_b:
            for p in range(start_a[i], end_a[i]):
                for r in range(start_b[j], end_b[j]):
                    g = math.sqrt(_gap2(lo_a[p, 0], lo_a[p, 1], lo_a[p, 2], hi_a[p, 0], hi_a[p, 1], hi_a[p, 2],
                                        lo_b[r, 0], lo_b[r, 1], lo_b[r, 2], hi_b[r, 0], hi_b[r, 1], hi_b[r, 2]))
                    if g < best:
                        best = g
            continue
        # split the node with more boxes (a leaf never); push the farther child first
        split_a = not leaf_a and (leaf_b or end_a[i] - start_a[i] >= end_b[j] - start_b[j])
        if top + 2 > stack.shape[0]:
            grown = np.empty((2 * stack.shape[0], 2), np.int64)
            grown[:top] = stack[:top]
            stack = grown
        if split_a:
            c1, c2 = 2 * i + 1, 2 * i + 2
            g1 = _gap2(box_a[c1, 0], box_a[c1, 1], box_a[c1, 2], box_a[c1, 3], box_a[c1, 4], box_a[c1, 5],
                       bb[0], bb[1], bb[2], bb[3], bb[4], bb[5])
            g2 = _gap2(box_a[c2, 0], box_a[c2, 1], box_a[c2, 2], box_a[c2, 3], box_a[c2, 4], box_a[c2, 5],
                       bb[0], bb[1], bb[2], bb[3], bb[4], bb[5])
            near, far = (c1, c2) if g1 <= g2 else (c2, c1)
            stack[top, 0], stack[top, 1] = far, j
            stack[top + 1, 0], stack[top + 1, 1] = near, j
        else:
            c1, c2 = 2 * j + 1, 2 * j + 2
            g1 = _gap2(ba[0], ba[1], ba[2], ba[3], ba[4], ba[5],
                       box_b[c1, 0], box_b[c1, 1], box_b[c1, 2], box_b[c1, 3], box_b[c1, 4], box_b[c1, 5])
            g2 = _gap2(ba[0], ba[1], ba[2], ba[3], ba[4], ba[5],
                       box_b[c2, 0], box_b[c2, 1], box_b[c2, 2], box_b[c2, 3], box_b[c2, 4], box_b[c2, 5])
            near, far = (c1, c2) if g1 <= g2 else (c2, c1)
            stack[top, 0], stack[top, 1] = i, far
            stack[top + 1, 0], stack[top + 1, 1] = i, near
        top += 2
    return best


def least_gap(lo_a: np.ndarray, hi_a: np.ndarray, lo_b: np.ndarray, hi_b: np.ndarray) -> float:
    """The least distance between a box of set a (rows of ``lo_a``, ``hi_a``: lowest and highest
    corners) and a box of set b; inf if either set is empty (module doc)."""
    if len(lo_a) == 0 or len(lo_b) == 0:
        return float("inf")
    sides = []
    for lo, hi in ((lo_a, hi_a), (lo_b, hi_b)):
        order = _morton_order(lo, hi)
        lo_s = np.ascontiguousarray(lo[order], np.float64)
        hi_s = np.ascontiguousarray(hi[order], np.float64)
        sides.append((lo_s, hi_s, *_node_boxes(lo_s, hi_s)))
    return float(_least_gap(*sides[0], *sides[1]))
