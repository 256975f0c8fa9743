"""How an independent reference's attitude sits on the IMU, against the recovery's trajectory.

Notation: ``R_ref(t)``, ``p_ref(t)``, ``R_rec(t)``, ``p_rec(t)``: world-from-IMU attitude and IMU
position of the reference and of the recovery's optimised trajectory; ``W``: the rotation from the
reference's world frame to the trajectory's; ``dR``: the constant IMU-frame rotation with
``R_rec ~ W R_ref dR``; ``u``: the IMU's mean up axis (in the IMU frame).

1. ``W`` aligns the centred positions (Kabsch, ``Rotation.align_vectors``): the world frames are
   tied by where the IMU went, not by its attitude.
2. ``dR`` is the chordal mean of ``(W R_ref)^T R_rec`` over the trajectory's stamps inside the
   reference (``Rotation.mean``); its spread is the RMS angle of the stamps about it.
3. Its rotation vector splits into heading (along ``u``) and tilt (perpendicular to ``u``).
4. A tilt of the attitude trades against a horizontal accelerometer bias: the specific force
   ``f ~ |g| u`` turned by ``tilt`` moves by ``|tilt| |g|``. A bias fitted with one attitude is off by
   about that much against the other, on the very same positions and velocities.

So when a recovered bias and a dataset's own bias disagree against the dataset's reference, the
offset says whether the two were fitted to different attitudes (e.g. a reference built through a
wrong extrinsic), which no bias can reconcile.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation

from pipeline.types import PoseSeries
from validation.reference import ReferenceStates, reference_from_states

#: Fewest trajectory stamps inside the reference for an offset to be reported.
MIN_STAMPS = 10


@dataclass(frozen=True)
class AttitudeOffset:
    """``R_rec ~ W R_ref dR`` (see the module docstring).

    Attributes:
        rotvec_deg: ``dR`` as a rotation vector in the IMU frame, [3] (deg).
        tilt_deg / heading_deg: Its parts perpendicular to and along the IMU's mean up axis (deg).
        spread_deg: RMS angle of the per-stamp rotations about ``dR`` (deg).
        acc_bias_equivalent_mps2: ``|g| sin|tilt|``: the horizontal accelerometer bias the tilt stands for.
        world_deg: Angle of ``W`` (deg); world_rms_m: RMS position residual after it (m).
        stamps: Trajectory stamps compared.
    """

    rotvec_deg: np.ndarray
    tilt_deg: float
    heading_deg: float
    spread_deg: float
    acc_bias_equivalent_mps2: float
    world_deg: float
    world_rms_m: float
    stamps: int

    def to_dict(self) -> dict[str, Any]:
        return {"rotvec_deg": [float(x) for x in self.rotvec_deg], "tilt_deg": self.tilt_deg,
                "heading_deg": self.heading_deg, "spread_deg": self.spread_deg,
                "acc_bias_equivalent_mps2": self.acc_bias_equivalent_mps2, "world_deg": self.world_deg,
                "world_rms_m": self.world_rms_m, "stamps": self.stamps}

    def note(self) -> str:
        return (f"the reference's attitude sits, on average, {np.linalg.norm(self.rotvec_deg):.2f} deg from the "
                f"recovery's as a rotation in the IMU frame (per-stamp spread {self.spread_deg:.2f} deg RMS over "
                f"{self.stamps} stamps): tilt {self.tilt_deg:.2f} deg, heading {self.heading_deg:.2f} deg. The tilt "
                f"trades against a horizontal accelerometer bias of {self.acc_bias_equivalent_mps2:.3f} m/s^2, so a "
                "bias fitted with the reference's attitude (e.g. the dataset's own) and the recovered one differ by "
                "about that much on the same positions: check the extrinsic the reference was built with")


def reference_attitude_offset(reference: ReferenceStates, trajectory: PoseSeries,
                              gravity_mps2: np.ndarray) -> AttitudeOffset | None:
    """The constant IMU-frame rotation from the reference's attitude to the trajectory's.

    Args:
        reference: An independent reference (its states at the IMU stamps).
        trajectory: The recovery's optimised IMU trajectory (IMU clock; any world frame).
        gravity_mps2: Gravity in the reference's world frame, [3].

    Returns:
        The offset, or None without orientations or with fewer than :data:`MIN_STAMPS` trajectory
        stamps inside the reference.
    """
    if trajectory.quat_wxyz is None:
        return None
    at = reference_from_states(reference, trajectory.t_ns)  # the reference at the trajectory's stamps
    ok = at.valid
    if ok.sum() < MIN_STAMPS:
        return None
    R_ref, p_ref = Rotation.from_matrix(at.R[ok]), at.p[ok]
    p_rec = trajectory.p_m[ok]
    W, _ = Rotation.align_vectors(p_rec - p_rec.mean(0), p_ref - p_ref.mean(0))
    resid = (p_rec - p_rec.mean(0)) - W.apply(p_ref - p_ref.mean(0))
    rel = (W * R_ref).inv() * Rotation.from_quat(trajectory.quat_wxyz[ok], scalar_first=True)
    dR = rel.mean()
    g = np.asarray(gravity_mps2, dtype=float)
    up = R_ref.inv().apply(-g / np.linalg.norm(g)).mean(axis=0)
    up /= np.linalg.norm(up)
    rv = dR.as_rotvec()
    tilt = float(np.linalg.norm(rv - (rv @ up) * up))
    return AttitudeOffset(rotvec_deg=np.degrees(rv), tilt_deg=float(np.degrees(tilt)),
                          heading_deg=float(np.degrees(abs(rv @ up))),
                          spread_deg=float(np.degrees(np.sqrt(np.mean((dR.inv() * rel).magnitude() ** 2)))),
                          acc_bias_equivalent_mps2=float(np.linalg.norm(g) * np.sin(tilt)),
                          world_deg=float(np.degrees(W.magnitude())),
                          world_rms_m=float(np.sqrt(np.mean(np.sum(resid**2, axis=1)))), stamps=int(ok.sum()))
