"""How far the estimated extrinsic ``T_imu_pose`` lies from a calibration file's, in its own sigmas.

A calibration file's extrinsic is a prior, not a truth (:class:`recovery.config.ExtrinsicMode`
PRIOR): the recovery estimates ``T_imu_pose`` where the motion makes it observable, and this
module says how far the estimate moved from the file's value and whether the data disagree with
the file beyond ``max_sigmas`` (then the file is off, or the tracked body was moved).

Notation: ``E_f`` the file's ``T_imu_pose``, ``E`` the estimate, ``dtheta = Log(R_f^T R)`` (tracked
frame, the tangent of ``E``'s marginal), ``dp = p - p_f`` (IMU frame). A difference's sigma is the
marginal's standard deviation along its own direction: ``sigma_u = sqrt(u^T Cov u)``, ``u = d / |d|``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from recovery.solver.rotations import matrix_to_rotvec


@dataclass(frozen=True)
class CalibrationDifference:
    """The estimated extrinsic against the calibration's.

    Attributes:
        rotation_deg: ``|dtheta|``. rotation_vector_deg: ``dtheta`` [3] (tracked frame).
        rotation_sigma_deg: 1-sigma of the estimate along ``dtheta`` (NaN without a marginal).
        translation_m: ``|dp|``. translation_vector_m: ``dp`` [3] (IMU frame).
        translation_sigma_m: 1-sigma of the estimate along ``dp`` (NaN without a marginal).
        max_sigmas: The threshold of :attr:`exceeds`.
    """

    rotation_deg: float
    rotation_vector_deg: np.ndarray
    rotation_sigma_deg: float
    translation_m: float
    translation_vector_m: np.ndarray
    translation_sigma_m: float
    max_sigmas: float

    @property
    def rotation_z(self) -> float:
        """``|dtheta| / sigma`` (NaN without a sigma)."""
        return _ratio(self.rotation_deg, self.rotation_sigma_deg)

    @property
    def translation_z(self) -> float:
        return _ratio(self.translation_m, self.translation_sigma_m)

    @property
    def exceeds(self) -> bool:
        """The data disagree with the file: a difference beyond ``max_sigmas`` of its sigma."""
        return any(z > self.max_sigmas for z in (self.rotation_z, self.translation_z) if math.isfinite(z))

    def sentence(self) -> str:
        """One line for warnings and reports."""
        return (f"the extrinsic T_imu_pose estimated from the data differs from the calibration's by "
                f"{self.rotation_deg:.2f} deg ({_sigmas(self.rotation_z)}) and {100 * self.translation_m:.1f} cm "
                f"({_sigmas(self.translation_z)}): the calibration file is off (or the tracked body was moved); "
                "the estimate was used")

    def to_dict(self) -> dict[str, Any]:
        return {"rotation_deg": self.rotation_deg, "rotation_vector_deg": [float(x) for x in self.rotation_vector_deg],
                "rotation_sigma_deg": self.rotation_sigma_deg, "rotation_sigmas": self.rotation_z,
                "translation_m": self.translation_m,
                "translation_vector_m": [float(x) for x in self.translation_vector_m],
                "translation_sigma_m": self.translation_sigma_m, "translation_sigmas": self.translation_z,
                "max_sigmas": self.max_sigmas, "exceeds": self.exceeds}


def _ratio(value: float, sigma: float) -> float:
    return float(value / sigma) if sigma > 0 and math.isfinite(sigma) else float("nan")


def _sigmas(z: float) -> str:
    return f"{z:.1f} sigma" if math.isfinite(z) else "no sigma"


def _sigma_along(d: np.ndarray, cov: np.ndarray | None) -> float:
    """``sqrt(u^T cov u)`` with ``u = d / |d|`` (the largest axis sigma for a zero difference)."""
    if cov is None:
        return float("nan")
    cov = np.asarray(cov, dtype=float)
    n = float(np.linalg.norm(d))
    if n == 0.0:
        return float(np.sqrt(np.max(np.diag(cov))))
    u = d / n
    return float(np.sqrt(max(float(u @ cov @ u), 0.0)))


def calibration_difference(T_file: np.ndarray, T_est: np.ndarray, extrinsic_cov: np.ndarray | None,
                           lever_arm_cov: np.ndarray | None, max_sigmas: float) -> CalibrationDifference:
    """The estimate ``T_est`` against the file's ``T_file`` (see the module docstring).

    Args:
        T_file / T_est: 4x4 ``T_imu_pose``.
        extrinsic_cov: [6, 6] Pose3-tangent marginal of the estimate (rotation, translation), or None.
        lever_arm_cov: [3, 3] marginal of the lever arm in the IMU frame (replaces the translation
            block, e.g. when a later solve refined the lever arm), or None.
        max_sigmas: Threshold of :attr:`CalibrationDifference.exceeds`.
    """
    T_file, T_est = np.asarray(T_file, dtype=float), np.asarray(T_est, dtype=float)
    dtheta = matrix_to_rotvec((T_file[:3, :3].T @ T_est[:3, :3])[None])[0]
    dp = T_est[:3, 3] - T_file[:3, 3]
    rot_cov = trans_cov = None
    if extrinsic_cov is not None:
        cov = np.asarray(extrinsic_cov, dtype=float)
        rot_cov = cov[:3, :3]
        R = T_est[:3, :3]
        trans_cov = R @ cov[3:, 3:] @ R.T  # tangent translation -> IMU frame
    if lever_arm_cov is not None:
        trans_cov = np.asarray(lever_arm_cov, dtype=float)
    return CalibrationDifference(
        rotation_deg=float(np.degrees(np.linalg.norm(dtheta))), rotation_vector_deg=np.degrees(dtheta),
        rotation_sigma_deg=float(np.degrees(_sigma_along(dtheta, rot_cov))) if rot_cov is not None else float("nan"),
        translation_m=float(np.linalg.norm(dp)), translation_vector_m=dp,
        translation_sigma_m=_sigma_along(dp, trans_cov), max_sigmas=float(max_sigmas))
