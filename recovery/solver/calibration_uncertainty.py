"""The estimated calibration's uncertainty in the bias sigmas (first-order propagation).

The full solve holds the clock offset and the extrinsic ``T_imu_pose`` at their estimates, so
its bias marginals are the covariance *given* the calibration. An error ``dc`` of the
calibration moves the solve's optimum by ``J dc`` (``J = d bias* / d c``), hence

    Cov_b = Cov_b|c + J Cov_c J^T,

with ``Cov_c`` the covariance of the values used, from the solves that estimated them (the
joint extrinsic solve's marginal, the lever-arm solve's, the clock-offset search's curvature).

``J`` costs no nonlinear solve. The solve's linear system at its optimum is augmented with one
variable ``C = dc`` = [extrinsic rotation (3), extrinsic translation (3) as the right-perturbation
tangent of ``T_imu_pose`` (GTSAM Pose3 order), clock offset (s)], whose whitened columns follow
from the measurements in closed form:

* a pose measured through the extrinsic, ``X_meas = Z E^-1``: a column ``Ad_E``;
* a pose stamped ``d`` later: a column ``-zeta`` (``zeta = [omega; R^T v]``, the body twist);
* the fused keyframe velocity: ``[0, R [omega]_x] Ad_E`` and ``-a``.

``J l_i`` (``l_i`` the columns of a square root of ``Cov_c``) comes either from the solve's own
Bayes tree (two back-substitutions per column) or from a partial elimination of everything but
``C``, the cheaper for the rank. The same columns give the cost's slope and curvature in one
calibration parameter (:func:`parameter_slope_and_information`), on which the clock offset's
refinement takes Newton steps (:mod:`recovery.recover`).

Neglected: the correlation between the calibration's error and the full solve's noise, and the
cross-covariance between the offset and the extrinsic. Why this rather than calibration
variables in the final solve, and the derivation: ``docs/internals.md``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import gtsam
import numpy as np

#: The augmented variable's key and its layout.
C_KEY = gtsam.Symbol("c", 0).key()
CALIBRATION_DIM = 7  # extrinsic rotation (3), extrinsic translation (3), clock offset (1)
OFFSET_INDEX = 6
#: Up to this rank of ``Cov_c``, ``J`` comes from back-substitutions through the solve's own Bayes
#: tree; above it, from one elimination of the augmented system. On the benchmark's 180 s (1800
#: keyframes) a pair of back-substitutions costs ~0.03 s, the elimination ~0.09 s.
BACKSUBSTITUTION_MAX_RANK = 2


@dataclass(frozen=True)
class CalibrationCovariance:
    """Covariance of the calibration held fixed in the full solve.

    Attributes:
        cov: [7, 7], rows/columns ``CALIBRATION_DIM`` (zero for what is known).
        parameters: Names of the uncertain parts (``extrinsic_rotation``, ``extrinsic_translation``,
            ``clock_offset``), for ``recovery.json``.
    """

    cov: np.ndarray
    parameters: tuple[str, ...]

    @classmethod
    def assemble(cls, *, extrinsic_cov: np.ndarray | None = None, lever_arm_cov: np.ndarray | None = None,
                 R_imu_pose: np.ndarray | None = None, offset_std_s: float | None = None
                 ) -> "CalibrationCovariance | None":
        """From the estimating solves' marginals; None when nothing was estimated.

        Args:
            extrinsic_cov: [6, 6] Pose3-tangent marginal of the joint extrinsic solve.
            lever_arm_cov: [3, 3] marginal of a later lever-arm solve (IMU frame; replaces the
                translation block); needs ``R_imu_pose`` [3, 3] to map it into the tangent.
            offset_std_s: 1-sigma of the estimated clock offset.
        """
        cov = np.zeros((CALIBRATION_DIM, CALIBRATION_DIM))
        names: list[str] = []
        if extrinsic_cov is not None:
            cov[:6, :6] = np.asarray(extrinsic_cov, dtype=float)
            names += ["extrinsic_rotation", "extrinsic_translation"]
        if lever_arm_cov is not None and R_imu_pose is not None:
            R = np.asarray(R_imu_pose, dtype=float)
            cov[:3, 3:6] = cov[3:6, :3] = 0.0
            cov[3:6, 3:6] = R.T @ np.asarray(lever_arm_cov, dtype=float) @ R  # tangent t = R_E^T dp
            names += [] if "extrinsic_translation" in names else ["extrinsic_translation"]
        if offset_std_s is not None and offset_std_s > 0:
            cov[OFFSET_INDEX, OFFSET_INDEX] = float(offset_std_s) ** 2
            names.append("clock_offset")
        return cls(0.5 * (cov + cov.T), tuple(names)) if names else None

    def sqrt_columns(self) -> np.ndarray:
        """``L`` [7, r] with ``L L^T = cov`` (eigen-decomposition, positive part)."""
        w, U = np.linalg.eigh(self.cov)
        keep = w > 1e-12 * max(float(w.max()), 1e-300)
        return U[:, keep] * np.sqrt(w[keep])


@dataclass(frozen=True)
class KeyframeKinematics:
    """What the measurement columns need per keyframe (from the solve's optimum).

    Attributes:
        R_world_imu: [K, 3, 3]. v_mps: World velocity [K, 3]. omega_radps: Body rate, bias-corrected
        [K, 3]. a_mps2: World acceleration [K, 3].
    """

    R_world_imu: np.ndarray
    v_mps: np.ndarray
    omega_radps: np.ndarray
    a_mps2: np.ndarray


def _skew(w: np.ndarray) -> np.ndarray:
    """[K, 3] -> [K, 3, 3] cross-product matrices."""
    S = np.zeros((len(w), 3, 3))
    S[:, 0, 1], S[:, 0, 2], S[:, 1, 2] = -w[:, 2], w[:, 1], -w[:, 0]
    S[:, 1, 0], S[:, 2, 0], S[:, 2, 1] = w[:, 2], -w[:, 1], w[:, 0]
    return S


def measurement_columns(kin: KeyframeKinematics, T_imu_pose: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """d(error)/dc of the pose factors [K, 6, 7] and of the fused velocity priors [K, 3, 7]."""
    Ad = gtsam.Pose3(np.asarray(T_imu_pose, dtype=float)).AdjointMap()
    K = len(kin.v_mps)
    pose = np.zeros((K, 6, CALIBRATION_DIM))
    pose[:, :, :6] = Ad
    v_body = np.einsum("kji,kj->ki", kin.R_world_imu, kin.v_mps)  # R^T v
    pose[:, :3, OFFSET_INDEX] = -kin.omega_radps
    pose[:, 3:, OFFSET_INDEX] = -v_body
    vel = np.zeros((K, 3, CALIBRATION_DIM))
    d_eta_t = np.einsum("kij,kjl->kil", kin.R_world_imu, _skew(kin.omega_radps))  # d v_err / d eta_t
    vel[:, :, :6] = np.einsum("kij,jl->kil", d_eta_t, Ad[3:, :])
    vel[:, :, OFFSET_INDEX] = -kin.a_mps2
    return pose, vel


def added_bias_variance(gfg: gtsam.GaussianFactorGraph, factors: list[tuple[int, int, str]],
                        columns: tuple[np.ndarray, np.ndarray], cal: CalibrationCovariance,
                        bias_keys: list[int], ordering: gtsam.Ordering | None = None,
                        tree: gtsam.GaussianBayesTree | None = None,
                        zero: gtsam.VectorValues | None = None) -> np.ndarray:
    """``diag(J Cov_c J^T)`` at ``bias_keys``, [M, 6] in (gyro, acc) order.

    Args:
        gfg: The solve's linearisation at its optimum (whitened JacobianFactors).
        factors: ``(graph index, keyframe, kind)`` of each pose (``"x"``) and velocity (``"v"``) factor.
        columns: :func:`measurement_columns`.
        cal: The calibration covariance.
        bias_keys: Keys of the biases wanted.
        ordering: Elimination order of every variable but ``C`` (default: COLAMD's).
        tree: ``gfg`` eliminated (the marginals' Bayes tree), with ``zero``, zeros for all of
            its variables: back-substitution through it when ``Cov_c``'s rank is at most
            :data:`BACKSUBSTITUTION_MAX_RANK` (see the module docstring).
    """
    pose_col, vel_col = columns
    # C in the coordinates of Cov_c's square root (its rank: 1 when only the offset is estimated)
    L = cal.sqrt_columns()
    pose_col, vel_col = pose_col @ L, vel_col @ L
    cols = [pose_col[k] if kind == "x" else vel_col[k] for _, k, kind in factors]  # [d, r] each
    if tree is not None and zero is not None and L.shape[1] <= BACKSUBSTITUTION_MAX_RANK:
        out = _added_by_backsubstitution(gfg, [i for i, _, _ in factors], cols, tree, zero, bias_keys)
        if out is not None:
            return out
    return _added_by_elimination(gfg, [i for i, _, _ in factors], cols, bias_keys, ordering)


def _bias_tangents(sol: gtsam.VectorValues, bias_keys: list[int]) -> np.ndarray:
    """The bias entries of ``sol`` in (gyro, acc) order, [M, 6] (ConstantBias tangent: [acc, gyro])."""
    d = np.array([sol.at(key) for key in bias_keys])
    return np.hstack([d[:, 3:], d[:, :3]])


def tree_as_bayes_net(tree: gtsam.GaussianBayesTree) -> gtsam.GaussianBayesNet:
    """The conditionals of ``tree``'s cliques as a Bayes net, every clique after its children (an
    elimination order), for solves with other right-hand sides
    (``GaussianBayesNet.backSubstituteTranspose`` / ``backSubstitute``)."""
    post: list[Any] = []
    stack = [(clique, False) for clique in tree.roots()]
    while stack:  # iterative post-order: a chain in time is thousands of cliques deep
        clique, children_done = stack.pop()
        if children_done:
            post.append(clique.conditional())
            continue
        stack.append((clique, True))
        stack.extend((clique[i], False) for i in range(clique.nrChildren()))
    net = gtsam.GaussianBayesNet()
    for conditional in post:
        net.push_back(conditional)
    return net


class _Measured:
    """The pose and velocity factors of a linearised solve as a graph of their own: their part
    ``A^T A`` of the Gauss-Newton Hessian times a vector per key, and ``-A^T b``. A factor's
    first key is the measured state (``X`` or ``V``); a pose factor may carry its correlated
    error state ``N`` (:mod:`recovery.solver.pose_error`) as a second key, which the calibration does
    not move (its columns are zero there)."""

    def __init__(self, gfg: gtsam.GaussianFactorGraph, indices: list[int]) -> None:
        self.graph = gtsam.GaussianFactorGraph()
        self.keys: list[int] = []
        for index in indices:
            factor = gfg.at(index)
            self.graph.push_back(factor)
            self.keys.append(factor.keys()[0])
        # one factor per key, else the columns are not one vector per key
        self.one_per_key = len(set(self.keys)) == len(self.keys)
        self.at_zero = self.graph.gradientAtZero()  # -A^T b
        self.zeros = gtsam.VectorValues(self.at_zero)
        self.zeros.setZero()

    def along(self, vectors: list[np.ndarray]) -> tuple[gtsam.VectorValues, gtsam.VectorValues]:
        """``x`` (``vectors`` on the measured states' keys, zero on the others) and ``A^T A x``."""
        given = gtsam.VectorValues()
        for key, vector in zip(self.keys, vectors):
            given.insert(key, vector)
        x = gtsam.VectorValues(self.zeros)
        x.update(given)
        return x, self.graph.gradient(x).subtract(self.at_zero)  # A^T (A x - b) + A^T b


def _on_every_variable(v: gtsam.VectorValues, zero: gtsam.VectorValues) -> gtsam.VectorValues:
    """``v`` with zeros for the other variables of ``zero`` (a right-hand side for the tree's net)."""
    out = gtsam.VectorValues(zero)
    out.update(v)
    return out


def _added_by_backsubstitution(gfg: gtsam.GaussianFactorGraph, indices: list[int], cols: list[np.ndarray],
                               tree: gtsam.GaussianBayesTree, zero: gtsam.VectorValues,
                               bias_keys: list[int]) -> np.ndarray | None:
    """``J l_i = -H^-1 A^T A x_i`` through ``tree`` (module docstring); None when a key carries
    more than one of the factors."""
    measured = _Measured(gfg, indices)
    if not measured.one_per_key:
        return None
    net = tree_as_bayes_net(tree)
    out = np.zeros((len(bias_keys), 6))
    for i in range(cols[0].shape[1]):
        g = _on_every_variable(measured.along([col[:, i] for col in cols])[1], zero)
        out += _bias_tangents(net.backSubstitute(net.backSubstituteTranspose(g)), bias_keys) ** 2
    return out


def _added_by_elimination(gfg: gtsam.GaussianFactorGraph, indices: list[int], cols: list[np.ndarray],
                          bias_keys: list[int], ordering: gtsam.Ordering | None) -> np.ndarray:
    """``J l_i`` from the augmented system with every variable but ``C`` eliminated (module docstring)."""
    unit = {n: gtsam.noiseModel.Unit.Create(n) for n in (3, 6)}
    replaced: dict[int, Any] = {}
    for index, col in zip(indices, cols):
        jf = gfg.at(index)
        A, b = jf.jacobian()
        keys = jf.keys()
        Ax = A[:, :col.shape[0]]  # the measured state's block
        if len(keys) == 1:
            replaced[index] = gtsam.JacobianFactor(keys[0], Ax, C_KEY, Ax @ col, b, unit[len(b)])
        else:  # with the correlated error state N as its second key
            replaced[index] = gtsam.JacobianFactor(keys[0], Ax, keys[1], A[:, col.shape[0]:], C_KEY, Ax @ col, b,
                                                   unit[len(b)])
    aug = gtsam.GaussianFactorGraph()
    for i in range(gfg.size()):
        f = gfg.at(i)
        if f is not None:
            aug.push_back(replaced.get(i, f))
    if ordering is None:
        ordering = [key for key in aug.keyVector() if key != C_KEY]
    bayes_net, _ = aug.eliminatePartialSequential(ordering)
    r = cols[0].shape[1]
    given = gtsam.VectorValues()
    given.insert(C_KEY, np.zeros(r))
    x0 = _bias_tangents(bayes_net.optimize(given), bias_keys)
    out = np.zeros((len(bias_keys), 6))
    for e_i in np.eye(r):
        given = gtsam.VectorValues()
        given.insert(C_KEY, e_i)
        out += (_bias_tangents(bayes_net.optimize(given), bias_keys) - x0) ** 2
    return out


def parameter_slope_and_information(gfg: gtsam.GaussianFactorGraph, tree: gtsam.GaussianBayesTree,
                                    factors: list[tuple[int, int, str]], columns: tuple[np.ndarray, np.ndarray],
                                    zero: gtsam.VectorValues, index: int) -> tuple[float, float] | None:
    """The solve's cost (GTSAM's, 0.5 chi^2) as a function of one calibration parameter's value.

    With ``x`` the parameter's measurement columns on the pose and velocity keys and ``A``,
    ``b`` those factors' whitened Jacobians and right-hand sides (``gfg``, linearised at the
    optimum; ``tree``: ``gfg`` eliminated):

    * slope: ``x^T A^T b``, the cost's derivative in the value used (the columns give the error
      when the true value lies ``dc`` beyond it: moving the value by ``+d`` is ``dc -> dc - d``);
    * information: ``x^T A^T A x - |R^-T A^T A x|^2``, its Gauss-Newton curvature with every
      other variable optimised again (the Schur complement; one forward substitution).

    Args:
        gfg / tree / factors / columns / zero: As for :func:`added_bias_variance`.
        index: The parameter's column (e.g. :data:`OFFSET_INDEX`).

    Returns:
        ``(slope, information)``; a Newton step on the value is ``-slope / information``, and
        ``information^-1/2`` its 1-sigma. None when a key carries more than one of the factors.
    """
    pose_col, vel_col = columns
    measured = _Measured(gfg, [i for i, _, _ in factors])
    if not measured.one_per_key:
        return None
    x, hx = measured.along([(pose_col[k] if kind == "x" else vel_col[k])[:, index] for _, k, kind in factors])
    y = tree_as_bayes_net(tree).backSubstituteTranspose(_on_every_variable(hx, zero))  # R^-T A^T A x
    return -float(x.dot(measured.at_zero)), float(x.dot(hx) - y.dot(y))
