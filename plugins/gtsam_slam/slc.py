"""Semantic loop closure: register observed object centroids against the map (paper 1, §V-C).

Given map centroids ``A`` (world frame, n×3) and currently observed centroids ``B`` (m×3, in a
*yaw-free* local frame: the body frame rotated by roll and pitch only, which the VIO measures
accurately), find subsets, an association, a yaw ψ and a translation t with
``p_B = R(ψ)ᵀ (p_A − t)`` (eq. 1), i.e. ``p_A = R(ψ) p_B + t``.

Everything here is pure numpy/scipy:

* :func:`align_yaw` — the closed form of eqs. (3)–(6) for a given association, and the residual
  of eq. (2);
* :func:`solve_exhaustive` — the paper's search over variations of A and B in decreasing order of
  cardinality (exponential; small sets and a reference);
* :func:`solve_scalable` — 2-point hypotheses drawn from pairs with matching distance invariants,
  scored against a KD-tree, then refined by one-to-one association and the same closed form.

Both solvers accept a solution with the same rule (:class:`SlcParams`): at least ``min_matches``
pairs, every matched pair within ``inlier_gate`` after alignment, RMS residual ``sqrt(R)`` at most
``tolerance``; the best solution has the most pairs, then the smallest residual. A second
solution with a clearly different transform and nearly as many pairs makes the match
*ambiguous* (e.g. a regular grid of chairs) and it is rejected rather than guessed.

Both solvers optionally take a :class:`SlcPrior`: the current estimate of the robot's yaw and
position and a bound on the plausible correction (the drift accumulated since the map was
built). Transforms outside the bound are not candidates at all, neither as the solution nor as a
rival, so a repeated layout whose shifted alignments imply an impossible correction is
disambiguated, while rivals within the bound still make the match ambiguous. Without a prior the
search is the paper's, over all transforms.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, field
from functools import lru_cache
from typing import NamedTuple

import numpy as np

from amslam.geometry import wrap_angle, yaw_matrix

#: :func:`amslam.geometry.wrap_angle` over arrays of angles (hypotheses are scored in bulk).

__all__ = [
    "SlcParams",
    "SlcPrior",
    "SlcSolution",
    "align_yaw",
    "solve_exhaustive",
    "solve_scalable",
]


@dataclass(frozen=True)
class SlcParams:
    """Acceptance rule and search settings shared by both solvers.

    Attributes:
        tolerance: largest accepted RMS residual per landmark, ``sqrt(R)`` of eq. (2), metres.
        inlier_gate: largest distance of any matched pair after alignment, metres.
        min_matches: fewest matched landmarks (three fix position and yaw, paper 1 §VI-C).
        ambiguity_ratio: a second solution whose transform differs by more than
            ``distinct_yaw`` / ``distinct_translation`` and matches at least this fraction of the
            best one's pairs makes the result ambiguous.
        distinct_yaw: yaw difference (rad) above which two solutions are different.
        distinct_translation: translation difference (m) above which two solutions are different.
        min_pair_distance: horizontal distance below which a pair of points does not define a
            yaw hypothesis (scalable solver).
        pair_tolerance: largest difference of the pair invariants (horizontal distance, height
            difference) for two pairs to form a hypothesis (scalable solver); inlier pairs need
            not all pass it, only a few do.
        exact_pairs: when B has at most this many pairs, hypotheses use the complete tolerance
            (twice the gate) instead of ``pair_tolerance``.
        max_refinements: hypotheses refined at most (scalable solver).
        preview: B points every hypothesis is first scored on; only the best ``4 × preview``
            hypotheses of a batch are scored on all of B (preemptive scoring).
        max_samples: point pairs of B drawn by the scalable solver before it gives up; when B has
            fewer pairs than this, all of them are used (deterministic).
        confidence: the scalable solver stops sampling once a solution with this probability of
            having been found exists (adaptive RANSAC stopping rule).
    """

    tolerance: float = 0.3
    inlier_gate: float = 0.5
    min_matches: int = 3
    ambiguity_ratio: float = 0.75
    distinct_yaw: float = 0.2
    distinct_translation: float = 0.6
    min_pair_distance: float = 0.5
    pair_tolerance: float = 0.25
    exact_pairs: int = 100
    max_refinements: int = 30
    preview: int = 8
    max_samples: int = 300
    confidence: float = 0.999


@dataclass(frozen=True)
class SlcPrior:
    """The current estimate of the transform and the largest plausible correction of it.

    B's frame is the robot's yaw-free local frame, so the transform of eq. (1) *is* the robot's
    world yaw and position: ``yaw`` and ``translation`` are their current (SLAM) estimates, and a
    registration implying a correction beyond ``max_yaw`` or ``max_translation`` is physically
    implausible (more drift than the odometry can have accumulated).

    The bounds are one number for all of A, or one per point of A: matching map point ``i``
    limits the correction to ``max_translation[i]`` / ``max_yaw[i]`` (e.g. the drift accumulated
    since that landmark was last observed), so a solution must respect the bound of every point
    it matches, i.e. the smallest.

    Attributes:
        yaw: estimated world yaw of B's frame, rad.
        translation: estimated world position of B's origin (3-vector).
        max_translation: largest plausible ``‖t − translation‖``, metres (scalar or per A point).
        max_yaw: largest plausible ``|ψ − yaw|`` (wrapped), rad (scalar or per A point).
    """

    yaw: float
    translation: np.ndarray
    max_translation: float | np.ndarray
    max_yaw: float | np.ndarray

    def __post_init__(self) -> None:
        object.__setattr__(self, "translation", np.asarray(self.translation, float).reshape(3))
        for name in ("max_translation", "max_yaw"):
            v = np.asarray(getattr(self, name), float)
            if v.ndim > 1 or np.any(v < 0) or not np.all(np.isfinite(v)):
                raise ValueError(f"{name} must be finite, non-negative, a scalar or one per A point")
            object.__setattr__(self, name, float(v) if v.ndim == 0 else v)

    def _bound(self, value: float | np.ndarray, a_idx: np.ndarray | None) -> np.ndarray | float:
        if np.ndim(value) == 0:
            return value
        if a_idx is None:
            return float(np.max(value))  # no association yet: the loosest bound over A
        return np.asarray(value)[np.asarray(a_idx, dtype=np.int64)].min(axis=-1)

    def admits(self, psi: np.ndarray | float, t: np.ndarray, a_idx: np.ndarray | None = None) -> np.ndarray:
        """Whether transforms ``(ψ, t)`` (N and N×3, or one) lie within the bound.

        Args:
            psi: yaw of each transform.
            t: translation of each transform.
            a_idx: the A points each transform matches (N×k, or k for one transform); only
                needed for per-point bounds (None: the loosest bound over A).
        """
        return self.near(psi, t, 0.0, 0.0, a_idx)

    def near(
        self,
        psi: np.ndarray | float,
        t: np.ndarray,
        yaw_slack: np.ndarray | float,
        t_slack: np.ndarray | float,
        a_idx: np.ndarray | None = None,
    ) -> np.ndarray:
        """Whether transforms lie within the bound widened by the given slacks (vectorised)."""
        t = np.asarray(t, float).reshape(-1, 3)
        if len(t) == 0:
            return np.zeros(0, dtype=bool)
        dyaw = np.abs(wrap_angle(np.asarray(psi, float).reshape(-1) - self.yaw))
        dt = np.linalg.norm(t - self.translation, axis=1)
        if a_idx is not None:
            a_idx = np.asarray(a_idx, dtype=np.int64).reshape(len(t), -1)
        max_yaw = self._bound(self.max_yaw, a_idx)
        max_t = self._bound(self.max_translation, a_idx)
        return (dyaw <= max_yaw + np.asarray(yaw_slack) + 1e-12) & (dt <= max_t + np.asarray(t_slack) + 1e-12)


@dataclass(frozen=True)
class SlcSolution:
    """Outcome of a registration.

    Attributes:
        accepted: whether the solution passed the acceptance rule and is not ambiguous.
        reason: a short human-readable verdict.
        pairs: k×2 int array of matched indices ``(index into A, index into B)``.
        yaw: ψ of eq. (6), radians in (-π, π].
        translation: t of eq. (3).
        residual: R of eq. (2) (mean squared distance, m²); ``sqrt`` of it is the RMS.
        runner_up: pairs of the best different solution, when one was found.
    """

    accepted: bool
    reason: str
    pairs: np.ndarray = field(default_factory=lambda: np.zeros((0, 2), dtype=int))
    yaw: float = 0.0
    translation: np.ndarray = field(default_factory=lambda: np.zeros(3))
    residual: float = float("inf")
    runner_up: int = 0

    @property
    def matched(self) -> int:
        return int(len(self.pairs))

    @property
    def rms(self) -> float:
        return float(math.sqrt(self.residual)) if np.isfinite(self.residual) else float("inf")

    def transform(self, points_b: np.ndarray) -> np.ndarray:
        """Map points of B's frame into A's frame: ``R(ψ) p + t``."""
        return np.asarray(points_b) @ yaw_matrix(self.yaw).T + self.translation


def align_yaw(pa: np.ndarray, pb: np.ndarray) -> tuple[float, np.ndarray, float]:
    """Closed-form yaw + translation aligning matched sequences (eqs. 2–6).

    Args:
        pa: k×3 points of A (world), ``pa[i]`` matched with ``pb[i]``.
        pb: k×3 points of B (yaw-free local frame).

    Returns:
        ``(ψ*, t*, R)``: yaw of eq. (6), translation of eq. (3) and the residual of eq. (2).
    """
    psi, t, res = _align_batch(np.asarray(pa, float)[None], np.asarray(pb, float)[None])
    return float(psi[0]), t[0], float(res[0])


def _align_batch(pa: np.ndarray, pb: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Vectorised :func:`align_yaw` over a leading batch axis (N×k×3 each)."""
    k = pa.shape[1]
    ma = pa.mean(axis=1)
    mb = pb.mean(axis=1)
    da = pa - ma[:, None]
    db = pb - mb[:, None]
    # M = Σ Δp_B Δp_Aᵀ; only the entries eqs. (4)–(6) use are formed.
    m11 = np.einsum("nk,nk->n", db[..., 0], da[..., 0])
    m22 = np.einsum("nk,nk->n", db[..., 1], da[..., 1])
    m12 = np.einsum("nk,nk->n", db[..., 0], da[..., 1])
    m21 = np.einsum("nk,nk->n", db[..., 1], da[..., 0])
    m33 = np.einsum("nk,nk->n", db[..., 2], da[..., 2])
    a = m11 + m22
    b = m12 - m21
    psi = np.arctan2(b, a)  # eq. (6)
    best_trace = np.hypot(a, b) + m33  # eq. (5)
    # Σ‖Δa − RΔb‖² = Σ‖Δa‖² + Σ‖Δb‖² − 2 tr(R M): eq. (2) at the optimum, without forming R.
    sq = np.einsum("nki,nki->n", da, da) + np.einsum("nki,nki->n", db, db)
    residual = np.maximum(sq - 2.0 * best_trace, 0.0) / k
    c, s = np.cos(psi), np.sin(psi)
    rmb = np.stack([c * mb[:, 0] - s * mb[:, 1], s * mb[:, 0] + c * mb[:, 1], mb[:, 2]], axis=1)
    t = ma - rmb  # eq. (3)
    return psi, t, residual


def _pair_errors(pa: np.ndarray, pb: np.ndarray, psi: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Distances ‖p_A − (R(ψ) p_B + t)‖ for batches (N×k×3, N, N×3) → N×k."""
    c, s = np.cos(psi)[:, None], np.sin(psi)[:, None]
    x = c * pb[..., 0] - s * pb[..., 1] + t[:, None, 0]
    y = s * pb[..., 0] + c * pb[..., 1] + t[:, None, 1]
    z = pb[..., 2] + t[:, None, 2]
    return np.sqrt((pa[..., 0] - x) ** 2 + (pa[..., 1] - y) ** 2 + (pa[..., 2] - z) ** 2)


@dataclass
class _Candidate:
    pairs: np.ndarray
    psi: float
    t: np.ndarray
    residual: float

    @property
    def k(self) -> int:
        return len(self.pairs)

    def differs(self, other: _Candidate, params: SlcParams) -> bool:
        """Whether the two transforms are apart (yaw or translation)."""
        return (
            abs(wrap_angle(self.psi - other.psi)) > params.distinct_yaw
            or float(np.linalg.norm(self.t - other.t)) > params.distinct_translation
        )

    def rival(self, other: _Candidate, params: SlcParams, by_association: bool = False) -> bool:
        """Whether ``other`` is a genuinely different alignment: transforms apart, and fewer than
        two shared pairs (two shared pairs pin the same transform; the gap is then noise).

        ``by_association`` (used under a prior): the transform distance is not required. Within a
        drift bound of a few decimetres, alignments a fraction of a chair pitch apart that match
        different landmarks are different data associations, which is what the loop closure
        fixes in the graph.
        """
        shared = len({tuple(x) for x in self.pairs.tolist()} & {tuple(x) for x in other.pairs.tolist()})
        return shared < 2 and (by_association or self.differs(other, params))


def _decide(
    best: _Candidate | None, runner: _Candidate | None, params: SlcParams, prior: SlcPrior | None = None
) -> SlcSolution:
    """The shared acceptance rule."""
    if best is None:
        where = "" if prior is None else " within the drift bound"
        return SlcSolution(False, f"no consistent set of {params.min_matches} or more landmarks{where}")
    sol = dict(pairs=best.pairs, yaw=wrap_angle(best.psi), translation=best.t, residual=best.residual)
    if runner is not None and runner.k >= params.ambiguity_ratio * best.k:
        return SlcSolution(
            False,
            f"ambiguous: another alignment matches {runner.k} of {best.k} landmarks",
            runner_up=runner.k,
            **sol,
        )
    return SlcSolution(
        True, f"matched {best.k} landmarks, rms {math.sqrt(best.residual):.3f} m", runner_up=0, **sol
    )


def _labels(labels: np.ndarray | list | None, n: int) -> np.ndarray:
    if labels is None:
        return np.zeros(n, dtype=np.int64)
    return np.asarray(labels)


def _encode_classes(ca: np.ndarray, cb: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Map labels of any hashable kind to shared small integers."""
    names = {c: i for i, c in enumerate(dict.fromkeys([*ca.tolist(), *cb.tolist()]))}
    return (
        np.array([names[c] for c in ca.tolist()], dtype=np.int64),
        np.array([names[c] for c in cb.tolist()], dtype=np.int64),
    )


# --------------------------------------------------------------------------------------------
# (a) exhaustive search — the paper's reference
# --------------------------------------------------------------------------------------------


@lru_cache(maxsize=64)
def _variations(n: int, k: int) -> np.ndarray:
    """All ordered k-subsets of range(n) as a P(n,k)×k array (cached: reused across calls)."""
    if k == 0:
        return np.zeros((1, 0), dtype=np.int64)
    return np.array(list(itertools.permutations(range(n), k)), dtype=np.int64).reshape(-1, k)


def solve_exhaustive(
    A: np.ndarray,
    B: np.ndarray,
    labels_a: np.ndarray | list | None = None,
    labels_b: np.ndarray | list | None = None,
    params: SlcParams | None = None,
    *,
    prior: SlcPrior | None = None,
    chunk: int = 200_000,
) -> SlcSolution:
    """The paper's exhaustive search (§V-C): variations of A × combinations of B, largest first.

    For k = min(n, m) down to ``min_matches``, every k-subset of B is paired with every
    class-consistent ordered k-subset of A; each association is scored by the closed form of
    eqs. (3)–(6). The first level holding a valid association ends the search (after the level is
    finished, to detect a runner-up). Running time is O(min(m,n)! 2^max(m,n)): small sets only.

    Args:
        A: n×3 map centroids (world).
        B: m×3 observed centroids (yaw-free local frame).
        labels_a: class of each A point (None: one class).
        labels_b: class of each B point.
        params: acceptance rule.
        prior: when given, only transforms within its bound are candidates (solution or rival).
        chunk: associations evaluated per vectorised batch (memory bound).
    """
    p = params or SlcParams()
    A = np.asarray(A, float).reshape(-1, 3)
    B = np.asarray(B, float).reshape(-1, 3)
    ca, cb = _encode_classes(_labels(labels_a, len(A)), _labels(labels_b, len(B)))
    n, m = len(A), len(B)
    best: _Candidate | None = None
    runner: _Candidate | None = None
    lowest = max(p.min_matches, 1)
    for k in range(min(n, m), lowest - 1, -1):
        var = _variations(n, k)
        var_cls = ca[var]
        level: list[_Candidate] = []
        for comb in itertools.combinations(range(m), k):
            comb = np.array(comb)
            ok = np.all(var_cls == cb[comb][None], axis=1)
            cand = var[ok]
            if len(cand) == 0:
                continue
            pb_one = B[comb]
            for s in range(0, len(cand), chunk):
                sel = cand[s : s + chunk]
                pa = A[sel]
                pb = np.broadcast_to(pb_one, pa.shape)
                psi, t, res = _align_batch(pa, pb)
                valid = res <= p.tolerance**2
                if not valid.any():
                    continue
                idx = np.flatnonzero(valid)
                if prior is not None:
                    idx = idx[prior.admits(psi[idx], t[idx], sel[idx])]
                err = _pair_errors(pa[idx], pb[idx], psi[idx], t[idx])
                idx = idx[np.all(err <= p.inlier_gate, axis=1)]
                for i in idx:
                    pairs = np.stack([sel[i], comb], axis=1)
                    level.append(_Candidate(pairs, float(psi[i]), t[i], float(res[i])))
        if level:
            level.sort(key=lambda c: c.residual)
            best = level[0]
            runner = next((c for c in level[1:] if best.rival(c, p, prior is not None)), None)
            if runner is None:
                # A smaller, different solution counts too (e.g. a shifted grid losing a row).
                runner = _best_different_below(A, B, ca, cb, best, k, p, chunk, prior)
            break
    return _decide(best, runner, p, prior)


def _best_different_below(
    A: np.ndarray,
    B: np.ndarray,
    ca: np.ndarray,
    cb: np.ndarray,
    best: _Candidate,
    k_best: int,
    p: SlcParams,
    chunk: int,
    prior: SlcPrior | None = None,
) -> _Candidate | None:
    """Largest valid solution below level ``k_best`` whose transform differs from ``best``
    (and lies within the prior's bound, when one is given)."""
    n, m = len(A), len(B)
    k_min = max(p.min_matches, math.ceil(p.ambiguity_ratio * k_best))
    for k in range(k_best - 1, k_min - 1, -1):
        var = _variations(n, k)
        var_cls = ca[var]
        found: list[_Candidate] = []
        for comb in itertools.combinations(range(m), k):
            comb = np.array(comb)
            cand = var[np.all(var_cls == cb[comb][None], axis=1)]
            for s in range(0, len(cand), chunk):
                sel = cand[s : s + chunk]
                pa = A[sel]
                pb = np.broadcast_to(B[comb], pa.shape)
                psi, t, res = _align_batch(pa, pb)
                idx = np.flatnonzero(res <= p.tolerance**2)
                if prior is not None:
                    idx = idx[prior.admits(psi[idx], t[idx], sel[idx])]
                if len(idx) == 0:
                    continue
                err = _pair_errors(pa[idx], pb[idx], psi[idx], t[idx])
                for i in idx[np.all(err <= p.inlier_gate, axis=1)]:
                    c = _Candidate(np.stack([sel[i], comb], axis=1), float(psi[i]), t[i], float(res[i]))
                    if best.rival(c, p, prior is not None):
                        found.append(c)
        if found:
            return min(found, key=lambda c: c.residual)
    return None


# --------------------------------------------------------------------------------------------
# (b) scalable solver — invariant-guided 2-point hypotheses, KD-tree scoring, closed-form refit
# --------------------------------------------------------------------------------------------


class _Scorer:
    """Class-aware nearest-neighbour queries against A.

    The class index is a 4th coordinate scaled far beyond any distance, so one KD-tree answers
    class-restricted nearest-neighbour queries for all classes at once.
    """

    SEP = 1.0e4

    def __init__(self, A: np.ndarray, ca: np.ndarray):
        from scipy.spatial import cKDTree

        self.A = A
        self.ca = ca
        self.tree = cKDTree(np.column_stack([A, ca * self.SEP]))

    def count(self, B: np.ndarray, cb: np.ndarray, psi: np.ndarray, t: np.ndarray, gate: float) -> np.ndarray:
        """Inliers (B points with an A point of their class within ``gate``) per hypothesis."""
        c, s = np.cos(psi)[:, None], np.sin(psi)[:, None]
        x = c * B[None, :, 0] - s * B[None, :, 1] + t[:, None, 0]
        y = s * B[None, :, 0] + c * B[None, :, 1] + t[:, None, 1]
        z = np.broadcast_to(B[None, :, 2], x.shape) + t[:, None, 2]
        w = np.broadcast_to(cb[None, :] * self.SEP, x.shape)
        q = np.stack([x, y, z, w], axis=-1).reshape(-1, 4)
        d, _ = self.tree.query(q, k=1, distance_upper_bound=gate)
        return np.isfinite(d).reshape(x.shape).sum(axis=1)


def _associate(
    A: np.ndarray, ca: np.ndarray, B: np.ndarray, cb: np.ndarray, psi: float, t: np.ndarray, gate: float
) -> np.ndarray:
    """One-to-one class-consistent association within ``gate`` (Hungarian on squared distances)."""
    from scipy.optimize import linear_sum_assignment

    pb = B @ yaw_matrix(psi).T + t
    d = np.linalg.norm(A[:, None, :] - pb[None, :, :], axis=2)
    bad = (ca[:, None] != cb[None, :]) | (d > gate)
    rows = np.flatnonzero(~bad.all(axis=1))
    cols = np.flatnonzero(~bad.all(axis=0))
    if len(rows) == 0 or len(cols) == 0:
        return np.zeros((0, 2), dtype=int)
    sub = np.where(bad[np.ix_(rows, cols)], 1.0e6, d[np.ix_(rows, cols)] ** 2)
    r, c = linear_sum_assignment(sub)
    keep = sub[r, c] < 1.0e6
    return np.stack([rows[r[keep]], cols[c[keep]]], axis=1)


def _trim(
    A: np.ndarray, B: np.ndarray, pairs: np.ndarray, p: SlcParams
) -> tuple[np.ndarray, float, np.ndarray, float] | None:
    """Fit, then drop the worst pair until the acceptance rule holds (or too few pairs remain)."""
    while len(pairs) >= p.min_matches:
        psi, t, res = align_yaw(A[pairs[:, 0]], B[pairs[:, 1]])
        err = np.linalg.norm(A[pairs[:, 0]] - (B[pairs[:, 1]] @ yaw_matrix(psi).T + t), axis=1)
        if res <= p.tolerance**2 and np.all(err <= p.inlier_gate):
            return pairs, psi, t, res
        pairs = np.delete(pairs, int(np.argmax(err)), axis=0)
    return None


def _refine(
    A: np.ndarray,
    ca: np.ndarray,
    B: np.ndarray,
    cb: np.ndarray,
    psi: float,
    t: np.ndarray,
    p: SlcParams,
    prior: SlcPrior | None = None,
) -> _Candidate | None:
    """Alternate association and closed-form alignment until the association is stable.

    A 2-point hypothesis can be off by up to twice the gate at the far end of B, so the first
    association uses a doubled gate; each fit is then trimmed (worst pair first) until it
    satisfies the acceptance rule, and points are re-associated at the gate with the new
    transform. The result satisfies the rule (and lies within the prior's bound), or None: a
    refinement drifting out of the bound stops at its last admissible fit.
    """
    pairs = _associate(A, ca, B, cb, psi, t, 2.0 * p.inlier_gate)
    best: _Candidate | None = None
    for _ in range(10):
        fit = _trim(A, B, pairs, p)
        if fit is None:
            return best
        pairs, psi, t, res = fit
        if prior is not None and not prior.admits(psi, t, pairs[:, 0])[0]:
            return best
        cand = _Candidate(pairs, psi, t, res)
        if best is not None and (cand.k, -cand.residual) <= (best.k, -best.residual):
            return best
        best = cand
        new = _associate(A, ca, B, cb, psi, t, p.inlier_gate)
        if len(new) == len(pairs) and np.array_equal(new[np.lexsort(new.T)], pairs[np.lexsort(pairs.T)]):
            return best
        pairs = new
    return best


def _polish(
    A: np.ndarray,
    ca: np.ndarray,
    B: np.ndarray,
    cb: np.ndarray,
    cand: _Candidate,
    p: SlcParams,
    prior: SlcPrior | None = None,
) -> _Candidate:
    """Single-pair swaps that lower the residual of eq. (2) at the same cardinality.

    The Hungarian association minimises distances at a fixed transform, while the acceptance rule
    ranks by the residual after refitting; so every swap of one matched A point for an unused A
    point of the same class near the B point is refitted (all swaps in one vectorised batch), and
    the best improving swap is taken until none improves.
    """
    best = cand
    for _ in range(len(cand.pairs)):
        b_idx = best.pairs[:, 1]
        pb = B[b_idx] @ yaw_matrix(best.psi).T + best.t
        used = np.zeros(len(A), dtype=bool)
        used[best.pairs[:, 0]] = True
        d2 = np.sum((pb[:, None, :] - A[None, :, :]) ** 2, axis=2)  # matched B point × A point
        near = (cb[b_idx][:, None] == ca[None, :]) & ~used[None, :] & (d2 <= (2.0 * p.inlier_gate) ** 2)
        rows, alts = np.nonzero(near)
        if len(rows) == 0:
            break
        swaps = np.broadcast_to(best.pairs, (len(rows), *best.pairs.shape)).copy()
        swaps[np.arange(len(rows)), rows, 0] = alts
        pa, pbb = A[swaps[..., 0]], B[swaps[..., 1]]
        psi, t, res = _align_batch(pa, pbb)
        err = _pair_errors(pa, pbb, psi, t)
        ok = (res < best.residual - 1e-12) & (res <= p.tolerance**2) & np.all(err <= p.inlier_gate, axis=1)
        if prior is not None:
            ok &= prior.admits(psi, t, swaps[..., 0])
        if not ok.any():
            break
        j = int(np.flatnonzero(ok)[np.argmin(res[ok])])
        best = _Candidate(swaps[j], float(psi[j]), t[j], float(res[j]))
    return best


def _may_reach_prior(
    prior: SlcPrior,
    psi: np.ndarray,
    t: np.ndarray,
    h_a: np.ndarray,
    h_b: np.ndarray,
    mid_b: np.ndarray,
    pair_a: np.ndarray,
    gate: float,
) -> np.ndarray:
    """Whether a 2-point hypothesis can belong to a solution within the prior's bound.

    If both points of the pair are inliers of a solution (ψ*, t*) (each within ``gate``), the
    pair vectors differ by at most 2·gate after rotation by ψ*, so the hypothesis yaw is within
    δ = asin(2·gate / max(h_A, h_B)) of ψ* (any yaw when 2·gate ≥ that length); the midpoints
    agree within ``gate``, so ‖t_h − t*‖ ≤ gate + 2 sin(δ/2) ‖m_B,xy‖. A hypothesis farther than
    these slacks beyond the bound cannot lead to an admissible solution through its own pair
    (whose two A points ``pair_a`` any such solution matches, so their bounds apply).
    """
    ratio = 2.0 * gate / np.maximum(np.maximum(h_a, h_b), 1e-12)
    delta = np.where(ratio < 1.0, np.arcsin(np.minimum(ratio, 1.0)), np.pi)
    t_slack = gate + 2.0 * np.sin(0.5 * delta) * np.hypot(mid_b[:, 0], mid_b[:, 1])
    return prior.near(psi, t, delta, t_slack, pair_a)


def solve_scalable(
    A: np.ndarray,
    B: np.ndarray,
    labels_a: np.ndarray | list | None = None,
    labels_b: np.ndarray | list | None = None,
    params: SlcParams | None = None,
    *,
    prior: SlcPrior | None = None,
    rng: np.random.Generator | None = None,
) -> SlcSolution:
    """Invariant-guided 2-point RANSAC with the closed form of eqs. (3)–(6).

    Two points fix yaw and translation. Under a yaw-only rotation a pair's horizontal distance and
    signed height difference are invariant, so a pair of B can only correspond to pairs of A with
    matching invariants (and classes): those are found by binary search in the sorted invariants
    of A's ordered pairs. Every such hypothesis is scored by counting B points that land within
    the gate of an A point of their class (one KD-tree query for all hypotheses of a batch). The
    best hypotheses are refined by one-to-one association + closed form until stable; a runner-up
    with a different transform is kept to detect ambiguity. Sampling stops by the usual adaptive
    rule once the best inlier ratio makes a miss unlikely (``params.confidence``).

    With a ``prior``, a hypothesis is dropped before scoring when no transform within the bound
    can have both of its points as inliers (a necessary condition, so nothing admissible is
    lost), the prior transform itself is one more hypothesis, and refined solutions outside the
    bound are discarded: neither solution nor rival.

    Args:
        A: n×3 map centroids (world).
        B: m×3 observed centroids (yaw-free local frame).
        labels_a: class of each A point (None: one class).
        labels_b: class of each B point.
        params: acceptance rule and search settings.
        prior: when given, only transforms within its bound are candidates (solution or rival).
        rng: generator for sampling B pairs (only used when B has more than ``max_samples`` pairs).
    """
    p = params or SlcParams()
    A = np.asarray(A, float).reshape(-1, 3)
    B = np.asarray(B, float).reshape(-1, 3)
    ca, cb = _encode_classes(_labels(labels_a, len(A)), _labels(labels_b, len(B)))
    if min(len(A), len(B)) < max(p.min_matches, 2):
        return _decide(None, None, p, prior)
    rng = rng or np.random.default_rng(0)
    pairs_a, pairs_b = _pairs_of_a(A, p), _pairs_of_b(B, p)
    if len(pairs_b.first) == 0 or len(pairs_a.first) == 0:
        return _decide(None, None, p, prior)
    hypotheses = _hypotheses(A, ca, B, cb, pairs_a, pairs_b, p, prior, rng)
    if hypotheses is None:
        return _decide(None, None, p, prior)
    cands = _refined_candidates(A, ca, B, cb, *hypotheses, p, prior)
    if not cands:
        return _decide(None, None, p, prior)
    cands.sort(key=lambda c: (-c.k, c.residual))
    best = _polish(A, ca, B, cb, cands[0], p, prior)
    runner = next((c for c in cands[1:] if best.rival(c, p, prior is not None)), None)
    return _decide(best, runner, p, prior)


class _PairsA(NamedTuple):
    """Ordered pairs of A (``first`` → ``second``) at least ``min_pair_distance`` apart
    horizontally, sorted by that distance (``horizontal``) for the binary search in
    :func:`_hypotheses_of`; ``vector`` = A[second] − A[first], ``angle`` its heading."""

    first: np.ndarray
    second: np.ndarray
    vector: np.ndarray
    horizontal: np.ndarray
    angle: np.ndarray


class _PairsB(NamedTuple):
    """Unordered pairs of B (``first`` < ``second``) at least ``min_pair_distance`` apart horizontally."""

    first: np.ndarray
    second: np.ndarray
    vector: np.ndarray
    horizontal: np.ndarray


def _pairs_of_a(A: np.ndarray, p: SlcParams) -> _PairsA:
    n = len(A)
    ia, ka = np.nonzero(~np.eye(n, dtype=bool))
    va = A[ka] - A[ia]
    ha = np.hypot(va[:, 0], va[:, 1])
    keep = ha >= p.min_pair_distance
    ia, ka, va, ha = ia[keep], ka[keep], va[keep], ha[keep]
    order = np.argsort(ha)
    ia, ka, va, ha = ia[order], ka[order], va[order], ha[order]
    return _PairsA(ia, ka, va, ha, np.arctan2(va[:, 1], va[:, 0]))


def _pairs_of_b(B: np.ndarray, p: SlcParams) -> _PairsB:
    jb, lb = np.triu_indices(len(B), 1)
    vb = B[lb] - B[jb]
    hb = np.hypot(vb[:, 0], vb[:, 1])
    keep = hb >= p.min_pair_distance
    return _PairsB(jb[keep], lb[keep], vb[keep], hb[keep])


def _hypotheses(
    A: np.ndarray,
    ca: np.ndarray,
    B: np.ndarray,
    cb: np.ndarray,
    pairs_a: _PairsA,
    pairs_b: _PairsB,
    p: SlcParams,
    prior: SlcPrior | None,
    rng: np.random.Generator,
) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """2-point hypotheses (yaw, translation, inlier count) of at least ``min_matches`` inliers,
    from B pairs in batches until the adaptive rule says enough; None when there are none."""
    m = len(B)
    n_pairs_b = len(pairs_b.first)
    sample_order = rng.permutation(n_pairs_b) if n_pairs_b > p.max_samples else np.arange(n_pairs_b)
    sample_order = sample_order[: p.max_samples]
    scorer = _Scorer(A, ca)
    # Small problems use the exact necessary condition (two points within the gate each give
    # invariants within twice the gate), so no consistent pair is missed; large ones the tighter
    # tolerance, relying on some of the many inlier pairs passing it.
    exact = n_pairs_b <= p.exact_pairs
    eps = 2.0 * p.inlier_gate if exact else p.pair_tolerance
    score_gate = 2.0 * p.inlier_gate if exact else p.inlier_gate
    preview = rng.permutation(m)[: max(p.preview, p.min_matches)] if m > p.preview else np.arange(m)
    hyps_psi: list[np.ndarray] = []
    hyps_t: list[np.ndarray] = []
    hyps_n: list[np.ndarray] = []
    best_count = 0
    if prior is not None:
        # The prior transform is a hypothesis of its own (the refinement takes it from there).
        n0 = scorer.count(B, cb, np.array([prior.yaw]), prior.translation[None], score_gate)
        if n0[0] >= p.min_matches:
            hyps_psi.append(np.array([prior.yaw]))
            hyps_t.append(prior.translation[None].copy())
            hyps_n.append(n0)
    needed = len(sample_order)
    batch = 24  # B pairs per round; 24 suffice at 50 % inliers (adaptive rule below)
    done = 0
    while done < min(needed, len(sample_order)):
        sel = sample_order[done : done + batch]
        done += len(sel)
        psi, t = _hypotheses_of(sel, A, ca, B, cb, pairs_a, pairs_b, eps, p, prior)
        if len(psi) == 0:
            continue
        if len(psi) > 4 * len(preview):
            # Preemptive scoring: a cheap look at a few B points, then all of B for the best.
            pre = scorer.count(B[preview], cb[preview], psi, t, score_gate)
            top = np.argpartition(-pre, 4 * len(preview))[: 4 * len(preview)]
            psi, t = psi[top], t[top]
        counts = scorer.count(B, cb, psi, t, score_gate)
        good = counts >= p.min_matches
        hyps_psi.append(psi[good])
        hyps_t.append(t[good])
        hyps_n.append(counts[good])
        if good.any():
            best_count = max(best_count, int(counts[good].max()))
            # Adaptive stopping: probability that a random pair of B holds two inliers.
            w = min(best_count / m, 1.0)
            w2 = max(w * (best_count - 1) / max(m - 1, 1), 1e-12)
            if w2 >= 1.0:
                needed = done
            else:
                needed = min(needed, math.ceil(math.log(1.0 - p.confidence) / math.log(1.0 - w2)))
    if not hyps_psi:
        return None
    psi_all = np.concatenate(hyps_psi)
    if len(psi_all) == 0:
        return None
    return psi_all, np.concatenate(hyps_t), np.concatenate(hyps_n)


def _hypotheses_of(
    sel: np.ndarray,
    A: np.ndarray,
    ca: np.ndarray,
    B: np.ndarray,
    cb: np.ndarray,
    pairs_a: _PairsA,
    pairs_b: _PairsB,
    eps: float,
    p: SlcParams,
    prior: SlcPrior | None,
) -> tuple[np.ndarray, np.ndarray]:
    """The transforms (yaw, translation) mapping the B pairs ``sel`` onto every A pair of the same
    classes whose invariants (horizontal distance, height difference) agree within ``eps``;
    under a prior, only those that may reach its bound (:func:`_may_reach_prior`)."""
    ia, ka, va, ha, ang_a = pairs_a
    jb, lb, vb, hb = pairs_b
    none = (np.zeros(0), np.zeros((0, 3)))
    lo = np.searchsorted(ha, hb[sel] - eps, side="left")
    hi = np.searchsorted(ha, hb[sel] + eps, side="right")
    cnt = hi - lo
    if cnt.sum() == 0:
        return none
    which = np.repeat(np.arange(len(sel)), cnt)
    idx_a = np.arange(cnt.sum()) - np.repeat(np.cumsum(cnt) - cnt, cnt) + np.repeat(lo, cnt)
    bsel = sel[which]
    ok = (
        (np.abs(va[idx_a, 2] - vb[bsel, 2]) <= eps)
        & (ca[ia[idx_a]] == cb[jb[bsel]])
        & (ca[ka[idx_a]] == cb[lb[bsel]])
    )
    idx_a, bsel = idx_a[ok], bsel[ok]
    if len(idx_a) == 0:
        return none
    psi = ang_a[idx_a] - np.arctan2(vb[bsel, 1], vb[bsel, 0])
    c, s = np.cos(psi), np.sin(psi)
    mb = 0.5 * (B[jb[bsel]] + B[lb[bsel]])
    ma = 0.5 * (A[ia[idx_a]] + A[ka[idx_a]])
    t = ma - np.stack([c * mb[:, 0] - s * mb[:, 1], s * mb[:, 0] + c * mb[:, 1], mb[:, 2]], axis=1)
    if prior is not None:
        pair_a = np.stack([ia[idx_a], ka[idx_a]], axis=1)
        keep = _may_reach_prior(prior, psi, t, ha[idx_a], hb[bsel], mb, pair_a, p.inlier_gate)
        psi, t = psi[keep], t[keep]
    return psi, t


def _refined_candidates(
    A: np.ndarray,
    ca: np.ndarray,
    B: np.ndarray,
    cb: np.ndarray,
    psi_all: np.ndarray,
    t_all: np.ndarray,
    n_all: np.ndarray,
    p: SlcParams,
    prior: SlcPrior | None,
) -> list[_Candidate]:
    """Refine the strongest hypotheses, one per distinct transform, best first. Hypotheses close
    to a solution already found, or very close to one whose refinement failed, are masked out."""
    cands: list[_Candidate] = []
    alive = np.ones(len(psi_all), dtype=bool)

    def mask_near(psi: float, t: np.ndarray, scale: float) -> None:
        near = (np.abs(wrap_angle(psi_all - psi)) <= scale * p.distinct_yaw) & (
            np.linalg.norm(t_all - t, axis=1) <= scale * p.distinct_translation
        )
        alive[near] = False

    for _ in range(p.max_refinements):
        if not alive.any():
            break
        h = int(np.argmax(np.where(alive, n_all, -1)))
        if cands and n_all[h] < p.ambiguity_ratio * max(c.k for c in cands):
            break
        cand = _refine(A, ca, B, cb, float(psi_all[h]), t_all[h], p, prior)
        alive[h] = False
        if cand is None:
            mask_near(float(psi_all[h]), t_all[h], 0.25)
            continue
        # Under a prior, nearby alignments with another association are rivals: mask less.
        mask_near(cand.psi, cand.t, 1.0 if prior is None else 0.25)
        if prior is None:
            twin = next((i for i, q in enumerate(cands) if not cand.differs(q, p)), None)
        else:
            twin = next((i for i, q in enumerate(cands) if not cand.rival(q, p, True)), None)
        if twin is None:
            cands.append(cand)
        elif (cand.k, -cand.residual) > (cands[twin].k, -cands[twin].residual):
            cands[twin] = cand
    return cands
