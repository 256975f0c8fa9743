"""Whether the accelerometer agrees with the calibration's extrinsic rotation once the gyro's rotation is free.

A gyro triad rotated against the accelerometer's (the rotation part of a misalignment) and the
extrinsic rotation ``R_imu_pose`` look the same to the gyro: a solve that estimates the extrinsic
(PRIOR, with a calibration file's value as a weak prior) turns it by the gyro's rotation, and the
accelerometer bias then absorbs gravity times that turn (0.5 deg: 0.085 m/s^2, nearly constant).
With the gyro's rotation an intrinsic term, only the accelerometer tells the extrinsic rotation:
the antisymmetric part of the fitted ``S_a`` is the rotation ``phi = log(R_cal R_est^T)`` from the
solve's IMU frame to the accelerometer's. Its tilt is hard to tell from a constant accelerometer
bias (only the attitude's changes separate them), so the data alone leave it ~0.1 deg uncertain,
but they can check the calibration file: when ``phi`` agrees with the file's
(``-R_est dtheta``, ``dtheta`` the solve's difference from the file), the solve's turn from the file
is the gyro's own rotation (:func:`calibration_agreement`; recovery.json reports it). Then the file
tells the accelerometer's rotation against the solve's (the gyro's) frame far better than the data:
the fit takes it as a prior on ``S_a``'s antisymmetric part, with a nearly orthogonal triad as one
on its symmetric off-diagonal part (:func:`rotation_prior`), so the accelerometer readings are
turned into the frame the solve uses instead of its bias absorbing gravity times the turn; the
extrinsic and the gyro are left as the solve has them. Where the file and the accelerometer
disagree, nothing changes.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation
from scipy.special import gammaincinv  # scipy.stats would add ~0.5 s to every recovery process

from recovery.intrinsics.posterior import IntrinsicsPrior

#: ``phi = A vec_row(S_a)``: the rotation vector of ``S_a``'s antisymmetric part (``[phi]x``).
_ANTISYMMETRIC = np.zeros((3, 9))
_ANTISYMMETRIC[0, 7], _ANTISYMMETRIC[0, 5] = 0.5, -0.5  # (S_zy - S_yz) / 2
_ANTISYMMETRIC[1, 2], _ANTISYMMETRIC[1, 6] = 0.5, -0.5  # (S_xz - S_zx) / 2
_ANTISYMMETRIC[2, 3], _ANTISYMMETRIC[2, 1] = 0.5, -0.5  # (S_yx - S_xy) / 2
#: ``(S_xy + S_yx) / 2``, ``(S_xz + S_zx) / 2``, ``(S_yz + S_zy) / 2``: the triad's non-orthogonality.
_SYMMETRIC = np.zeros((3, 9))
_SYMMETRIC[0, [1, 3]] = _SYMMETRIC[1, [2, 6]] = _SYMMETRIC[2, [5, 7]] = 0.5
#: The file's rotation is used when the accelerometer's differs from it by less than this quantile
#: of chi-square with 3 degrees of freedom.
AGREEMENT_QUANTILE = 0.997


def chi2_quantile(q: float, dof: int) -> float:
    """The ``q`` quantile of the chi-square distribution with ``dof`` degrees of freedom (``chi2.ppf``)."""
    return float(2.0 * gammaincinv(0.5 * dof, q))


def calibration_agreement(acc_terms: np.ndarray, acc_cov: np.ndarray, report: Mapping[str, Any]) -> dict | None:
    """The accelerometer's rotation against the calibration file's; None without a file to compare with.

    Args:
        acc_terms: ``S_a`` fitted on the solve's trajectory (row-major [9]), raw readings.
        acc_cov: Its covariance [9, 9].
        report: The solve's ``recovery.json`` data (``extrinsic.mode`` ``prior``, its
            ``difference_from_calibration`` and ``T_imu_pose``).

    Returns:
        ``{"agrees", "mahalanobis_sq", "threshold", "accelerometer_rotation_rad", "sigma_rad",
        "calibration_rotation_rad"}`` (rotations in the solve's IMU frame).
    """
    phi_cal = calibration_rotation(report)
    if phi_cal is None:
        return None
    phi = _ANTISYMMETRIC @ np.asarray(acc_terms, dtype=float).ravel()
    cov = _ANTISYMMETRIC @ np.asarray(acc_cov, dtype=float) @ _ANTISYMMETRIC.T
    d = phi - phi_cal
    m2 = float(d @ np.linalg.solve(cov, d))
    threshold = chi2_quantile(AGREEMENT_QUANTILE, 3)
    return {"agrees": bool(m2 <= threshold), "mahalanobis_sq": m2, "threshold": threshold,
            "accelerometer_rotation_rad": phi.tolist(), "sigma_rad": np.sqrt(np.diag(cov)).tolist(),
            "calibration_rotation_rad": phi_cal.tolist()}


def calibration_rotation(report: Mapping[str, Any]) -> np.ndarray | None:
    """``phi_cal`` [3] (rad): the calibration file's IMU frame against the solve's, in the solve's IMU frame
    (the rotation vector of ``S_a``'s antisymmetric part if the accelerometer's frame is the file's); None
    unless the solve estimated the extrinsic with the file as its prior (``extrinsic.mode`` ``prior``)."""
    extrinsic = report.get("extrinsic") if isinstance(report.get("extrinsic"), Mapping) else {}
    diff = extrinsic.get("difference_from_calibration")
    pose = report.get("T_imu_pose")
    if extrinsic.get("mode") != "prior" or not isinstance(diff, Mapping) or not isinstance(pose, Mapping):
        return None
    q = np.asarray(pose["quat_wxyz"], dtype=float)
    R_est = Rotation.from_quat(q[[1, 2, 3, 0]]).as_matrix()
    return -R_est @ np.radians(np.asarray(diff["rotation_vector_deg"], dtype=float))


def rotation_prior(report: Mapping[str, Any], applied_acc_terms: np.ndarray, prior: IntrinsicsPrior = IntrinsicsPrior()
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """Prior rows ``(H [6, 9], target [6], sigma [6])`` on a fit's ``S_a`` (row-major [9]), None when the solve did
    not estimate the extrinsic against a file.

    The accelerometer triad is the calibration file's frame (its rotation against the solve's is
    :func:`calibration_rotation` of the solve ``report``, within ``prior.calibration_rotation_rad``) and nearly
    orthogonal (its symmetric off-diagonal part within ``prior.non_orthogonality``): a tilt term (``S_xz``,
    ``S_yz``, times ``f_z ~ g``), which the data cannot tell from a constant bias, is then the file's rotation.
    Both less what the readings the fit sees were corrected by already (``applied_acc_terms``: ``M_a - I`` [3, 3];
    first order)."""
    phi_cal = calibration_rotation(report)
    if phi_cal is None:
        return None
    applied = np.asarray(applied_acc_terms, dtype=float).ravel()
    H = np.vstack([_ANTISYMMETRIC, _SYMMETRIC])
    target = np.concatenate([phi_cal - _ANTISYMMETRIC @ applied, -_SYMMETRIC @ applied])
    return H, target, np.repeat([float(prior.calibration_rotation_rad), float(prior.non_orthogonality)], 3)
