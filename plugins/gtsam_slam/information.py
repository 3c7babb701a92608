"""Covariances and the information gain of virtual factors (paper 1, eq. 10).

The factor graph is linearised once at the current estimate into its whitened sparse Jacobian
``A`` (gtsam's ``sparseJacobian_``, columns in sorted-key order); the information matrix
``H = AᵀA`` is factorised once (SuperLU). A virtual odometry factor between the current pose
``x_t`` and an old key pose ``x_lc`` adds the rank-6 term ``JᵀJ`` (J: its whitened 6×12 Jacobian
on ``[x_t, x_lc]``), so by Woodbury

    Σ⁺ = Σ − Σ_{:,S} Jᵀ (I + J Σ_SS Jᵀ)⁻¹ J Σ_{S,:},   S = {x_t, x_lc}

and the trace reduction over a set of variables V is

    IG = tr(Σ_V) − tr(Σ⁺_V) = tr( W⁻¹ J Σ_{S,V} Σ_{V,S} Jᵀ ),   W = I + J Σ_SS Jᵀ.

Only the columns of Σ belonging to ``x_t`` (shared) and to each candidate ``x_lc`` are needed:
6 triangular solves per candidate with the one factorisation. The measurement of the virtual
factor is the current relative estimate, so its error is zero and the estimate does not move:
only the covariance changes, as eq. (10) requires.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import gtsam
import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla
from threadpoolctl import threadpool_limits

from amslam.lib.slc_gain import trace_reduction

__all__ = ["LinearizedGraph", "brute_force_information_gain"]


@dataclass
class LinearizedGraph:
    """A factorised information matrix with the column block of every variable.

    Attributes:
        keys: the graph's variable keys, sorted (gtsam's column order).
        offsets: first column of each key.
        dims: tangent dimension of each key.
        lu: SuperLU factorisation of ``H = AᵀA``.
        size: number of columns of H.
    """

    keys: list[int]
    offsets: dict[int, int]
    dims: dict[int, int]
    lu: spla.SuperLU
    size: int

    @staticmethod
    def build(graph: gtsam.NonlinearFactorGraph, values: gtsam.Values) -> LinearizedGraph:
        """Linearise ``graph`` at ``values`` and factorise its information matrix."""
        lin = graph.linearize(values)
        keys = sorted(int(k) for k in lin.keyVector())
        zero = values.zeroVectors()  # each variable's tangent vector: Pose3 6, Point3 3, Unit3 2, ...
        dims = {k: int(zero.at(k).size) for k in keys}
        offsets: dict[int, int] = {}
        col = 0
        for k in keys:
            offsets[k] = col
            col += dims[k]
        S = lin.sparseJacobian_()
        keep = S[1] <= col  # the last column (index col+1, 1-based) is the right-hand side b
        rows = S[0, keep].astype(np.int64) - 1
        cols = S[1, keep].astype(np.int64) - 1
        A = sp.csc_matrix((S[2, keep], (rows, cols)), shape=(int(rows.max()) + 1, col))
        H = (A.T @ A).tocsc()
        lu = spla.splu(H, permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0, options={"SymmetricMode": True})
        return LinearizedGraph(keys, offsets, dims, lu, col)

    def columns(self, keys: Sequence[int]) -> np.ndarray:
        """The columns of Σ = H⁻¹ that belong to ``keys`` (size × Σdims)."""
        idx = np.concatenate([np.arange(self.offsets[k], self.offsets[k] + self.dims[k]) for k in keys])
        out = np.empty((self.size, len(idx)))
        # SuperLU's multi-RHS triangular solves call BLAS; on a busy machine a threaded BLAS made
        # them 10–30× slower (6 RHS, 6.6k unknowns: 20 ms threaded vs 1.5 ms single-threaded), and
        # blocks of one pose's 6 columns were fastest. So: one BLAS thread, 6 columns at a time.
        with threadpool_limits(limits=1, user_api="blas"):
            for s in range(0, len(idx), 6):
                E = np.zeros((self.size, min(6, len(idx) - s)), order="F")
                E[idx[s : s + 6], np.arange(E.shape[1])] = 1.0
                out[:, s : s + 6] = self.lu.solve(E)
        return out

    def index(self, keys: Sequence[int]) -> np.ndarray:
        """Row indices of ``keys`` in H's ordering."""
        if not keys:
            return np.zeros(0, dtype=np.int64)
        return np.concatenate([np.arange(self.offsets[k], self.offsets[k] + self.dims[k]) for k in keys])

    def marginal(self, key: int) -> np.ndarray:
        """Marginal covariance of one variable."""
        cols = self.columns([key])
        i = self.index([key])
        return cols[i]

    def information_gain(
        self,
        current: int,
        candidates: Sequence[int],
        jacobians: Sequence[np.ndarray],
        over: Sequence[int] | None = None,
    ) -> np.ndarray:
        """Eq. (10) for many virtual factors, each between ``current`` and one candidate.

        Args:
            current: key of the current pose x_t.
            candidates: keys of the old key poses x_lc.
            jacobians: for each candidate, the whitened 6×12 Jacobian of its virtual factor on
                ``[x_t, x_lc]``.
            over: keys whose covariance trace is measured (None: every variable).

        Returns:
            The trace reduction of each candidate (each evaluated alone).
        """
        rows = None if over is None else self.index(list(over))
        lc_keys = [k for k in dict.fromkeys(candidates) if k != current]
        block = self.columns([current, *lc_keys])  # size × 6(1+C): one multi-RHS solve
        it = self.index([current])
        col_of = {current: slice(0, 6)}
        for j, k in enumerate(lc_keys):
            col_of[k] = slice(6 * (j + 1), 6 * (j + 2))
        out = np.zeros(len(candidates))
        for c, (k, J) in enumerate(zip(candidates, jacobians, strict=True)):
            if k == current:
                continue
            ik = self.index([k])
            C = np.hstack([block[:, col_of[current]], block[:, col_of[k]]])  # Σ_{:,S}
            idx = np.concatenate([it, ik])
            CV = C if rows is None else C[rows]
            out[c] = trace_reduction(C[idx], CV.T @ CV, J)
        return out

    def joint_blocks(
        self, keys: Sequence[int], over: Sequence[int] | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """``Σ_SS`` and ``Σ_{S,V} Σ_{V,S}`` for the variables ``S = keys`` (each once), ``V = over``
        (None: every variable): what eq. (10) of any set of factors on ``S`` needs
        (:class:`amslam.types.SlcGainModel`)."""
        block = self.columns(list(keys))
        CV = block if over is None else block[self.index(list(over))]
        return block[self.index(list(keys))], CV.T @ CV


def virtual_factor(
    key_t: int, key_lc: int, values: gtsam.Values, noise: gtsam.noiseModel.Base
) -> tuple[gtsam.BetweenFactorPose3, np.ndarray]:
    """The virtual odometry factor x_t → x_lc at zero error and its whitened 6×12 Jacobian."""
    Tt = values.atPose3(key_t)
    Tl = values.atPose3(key_lc)
    factor = gtsam.BetweenFactorPose3(key_t, key_lc, Tt.between(Tl), noise)
    A, _ = factor.linearize(values).jacobian()
    return factor, A


def brute_force_information_gain(
    graph: gtsam.NonlinearFactorGraph,
    values: gtsam.Values,
    factor: gtsam.NonlinearFactor,
    over: Sequence[int],
) -> float:
    """Reference for eq. (10): clone the graph, add the factor, recompute every marginal."""

    def trace(g: gtsam.NonlinearFactorGraph) -> float:
        marginals = gtsam.Marginals(g, values)
        return float(sum(np.trace(marginals.marginalCovariance(k)) for k in over))

    clone = gtsam.NonlinearFactorGraph(graph)
    before = trace(clone)
    clone.add(factor)
    return before - trace(clone)
