"""Noise strengths from the data: maximum (Laplace) evidence over a grid.

Datasheet bias random walks are often off by 10x, and the right pose noise of a
mocap system is rarely known. For a candidate noise model theta the marginal
likelihood of all measurements is approximated around the optimum x*:

    log p(z | theta) ~= -E(x*) - sum_f log Z_f(theta) - 0.5 log det H(x*)

(``E`` = 0.5 sum of squared whitened residuals, ``Z_f`` the Gaussian normaliser
of factor f, ``H`` the Gauss-Newton Hessian, obtained from GTSAM as the log
determinant of the eliminated Bayes net; for keyframes fused from several pose
samples, plus the Gaussian likelihood of the samples' scatter about their
keyframes, :class:`recovery.solver.fusion.WithinBinStats`). It is maximised coordinate-wise over
inflation factors of (1) the pose sigmas, (2) the gyro random walk, (3) the acc
random walk, on a decimated graph over the calibration window, from a start at 10x the
calibration's walks and, where they score higher, again from the calibration's own values (a
file written by an earlier search holds its optimum). The random walk
is a continuous-time density, so decimation changes how much information the
window carries but not what the optimum estimates.

What it costs: each coordinate is a bracketing search on the grid with a parabola
through the best point and its neighbours. The window is preintegrated once
(:class:`recovery.solver.preintegration.NoiseBasis`: the random walks re-weight it exactly). The
first candidate is solved; a random-walk candidate next to a solved one takes one
Gauss-Newton step from that optimum (:func:`recovery.solver.graph.evidence_step`), whose log
evidence is close to the full solve's on the scale of the differences between candidates.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from pipeline.types import PoseSourceKind
from recovery.config import NoiseEstimation, PoseSigmaMethod, RecoveryConfig
from recovery.solver.factors import noise_basis
from recovery.solver.graph import evidence_step, solve_window
from recovery.solver.window import KeyframePoses, SolveOptions, WindowInit
from recovery.solver.pose_error import PoseErrorModel
from recovery.solver.preintegration import ImuNoise, MidpointSamples

log = logging.getLogger(__name__)

POSE_SCALES = (0.25, 0.5, 1.0, 2.0, 4.0)


@dataclass
class NoiseChoice:
    """The chosen noise model and how it was found.

    Attributes:
        imu: IMU noise actually used.
        position_sigma_m / rotation_sigma_rad: Pose noise actually used.
        gyro_rw_scale / acc_rw_scale / pose_scale: Chosen factors relative to the
            calibration / defaults.
        pose_method: How the pose sigmas were chosen (with ``method`` FIXED: as given).
        method: Evidence search or fixed (as given).
        table: Every evaluated candidate with its log evidence.
        pose_error: The pose stream's time-correlated error (:mod:`recovery.solver.pose_error`), None: white only.
        gyro_density_scale / acc_density_scale: Chosen factors of the white noise densities.
    """

    imu: ImuNoise
    position_sigma_m: float
    rotation_sigma_rad: float
    gyro_rw_scale: float = 1.0
    acc_rw_scale: float = 1.0
    pose_scale: float = 1.0
    method: NoiseEstimation = NoiseEstimation.FIXED
    table: list[dict[str, float]] = field(default_factory=list)
    pose_method: PoseSigmaMethod = PoseSigmaMethod.EVIDENCE
    pose_error: PoseErrorModel | None = None
    gyro_density_scale: float = 1.0
    acc_density_scale: float = 1.0

    def to_dict(self) -> dict:
        return {
            "pose_error": None if self.pose_error is None else self.pose_error.to_dict(),
            "gyro_noise_density_scale": float(self.gyro_density_scale),
            "acc_noise_density_scale": float(self.acc_density_scale),
            **self.imu.to_dict(),
            "position_sigma_m": float(self.position_sigma_m),
            "rotation_sigma_rad": float(self.rotation_sigma_rad),
            "gyro_random_walk_scale": float(self.gyro_rw_scale),
            "acc_random_walk_scale": float(self.acc_rw_scale),
            "pose_sigma_scale": float(self.pose_scale),
            "pose_sigma_method": (self.pose_method if self.method is NoiseEstimation.EVIDENCE
                                  else PoseSigmaMethod.FIXED).value,
            "method": self.method.value,
            "candidates": self.table,
        }


def _argmax_parabolic_log(scales: list[float], ev: list[float]) -> float:
    """Best scale; refined by a parabola in log-scale when the optimum is interior (and not next to 0)."""
    i = int(np.nanargmax(ev))
    if 0 < i < len(scales) - 1 and all(math.isfinite(e) for e in ev[i - 1:i + 2]) and scales[i - 1] > 0:
        x = np.log(scales[i - 1:i + 2])
        y = np.asarray(ev[i - 1:i + 2])
        a, b, _ = np.polyfit(x, y, 2)
        if a < 0:
            xv = -b / (2 * a)
            if x[0] <= xv <= x[2]:
                return float(math.exp(xv))
    return float(scales[i])


def _grid_index(grid: list[float], value: float) -> int:
    """The grid point nearest ``value`` in log scale (0 only for 0)."""
    if value <= 0:
        return int(np.argmin(grid))
    logs = [abs(math.log(g) - math.log(value)) if g > 0 else math.inf for g in grid]
    return int(np.argmin(logs))


def _imu_noise(base: ImuNoise, gyro_rw_scale: float, acc_rw_scale: float, gyro_density_scale: float = 1.0,
               acc_density_scale: float = 1.0) -> ImuNoise:
    """``base`` with its random walks and white noise densities scaled."""
    return replace(base, gyro_random_walk=base.gyro_random_walk * gyro_rw_scale,
                   acc_random_walk=base.acc_random_walk * acc_rw_scale,
                   gyro_noise_density=base.gyro_noise_density * gyro_density_scale,
                   acc_noise_density=base.acc_noise_density * acc_density_scale)


@dataclass(frozen=True)
class PoseErrorGrid:
    """Candidates of the correlated pose error (:mod:`recovery.solver.pose_error`) for the evidence search.

    Attributes:
        sigma_scales: Stationary sigmas in units of the white per-sample sigma (0: none).
        taus_s: Correlation times.
    """

    sigma_scales: tuple[float, ...]
    taus_s: tuple[float, ...]


_STATE_KEYS = ("g", "a", "gn", "an", "p", "rs", "rt", "ps", "pt")


class _EvidenceSearch:
    """Log evidence of noise candidates on one window, cached, each warm-started from the best so far.

    A candidate is a state over ``_STATE_KEYS``: random-walk scales (g, a), white-density
    scales (gn, an), the pose-sigma scale (p) and the correlated pose error's sigma scale and
    correlation time per axis group (rs, rt rotation; ps, pt position).
    """

    def __init__(self, samples: MidpointSamples, kf: KeyframePoses, base_imu: ImuNoise, base_position_sigma_m: float,
                 base_rotation_sigma_rad: float, T_imu_pose: np.ndarray, opts: SolveOptions,
                 init: WindowInit | None, pose_error: PoseErrorGrid | None, start: dict[str, float]):
        self.samples, self.kf, self.base_imu, self.T_imu_pose, self.opts = samples, kf, base_imu, T_imu_pose, opts
        self.base_position_sigma_m, self.base_rotation_sigma_rad = base_position_sigma_m, base_rotation_sigma_rad
        self.pose_error = pose_error
        self.table: list[dict[str, float]] = []
        self.cache: dict[tuple[float, ...], float] = {}
        # Warm start of each candidate: the optimum of the best candidate so far (same graph, nearby
        # noise: LM needs ~2 iterations instead of ~5, and the optimum is the same). From the best one,
        # not the last one: a candidate far off (e.g. a pose sigma 30x too small for a position-only
        # stream over minutes) can settle in a wrong attitude minimum, and chaining from it would
        # carry that minimum into every later candidate.
        self.warm: dict[str, Any] = {"init": init, "ev": float("-inf"), "pose": None}
        self.like: dict[tuple[float, ...], Any] = {}  # per pose model: the last evidence step's graph
        self.within = kf.within_bin()
        # one preintegration for every candidate, at the start's noise and bias (the candidates differ
        # in their random walks only, which re-weight it exactly: NoiseBasis)
        self.basis = noise_basis(samples, _imu_noise(base_imu, start["g"], start["a"]), opts, init)

    def model_of(self, st: dict[str, float]) -> PoseErrorModel | None:
        """The correlated pose error of a state (without a pose-error grid: the fixed one of the options)."""
        if self.pose_error is None:
            return self.opts.pose_error
        return PoseErrorModel(self.base_rotation_sigma_rad * st["rs"], st["rt"],
                              self.base_position_sigma_m * st["ps"], st["pt"])

    def evaluate(self, st: dict[str, float]) -> float:
        """Log evidence of one state (-inf when its solve fails); cached and tabled."""
        key = tuple(round(st[k], 6) for k in _STATE_KEYS)
        if key not in self.cache:
            self.cache[key] = ev = self._solve(st, key[4:])
            self.table.append({"gyro_rw_scale": st["g"], "acc_rw_scale": st["a"], "gyro_density_scale": st["gn"],
                               "acc_density_scale": st["an"], "pose_scale": st["p"],
                               **({} if self.pose_error is None else {
                                   "rotation_error_sigma_scale": st["rs"], "rotation_error_tau_s": st["rt"],
                                   "position_error_sigma_scale": st["ps"], "position_error_tau_s": st["pt"]}),
                               "log_evidence": float(ev)})
        return self.cache[key]

    def _solve(self, st: dict[str, float], pose_key: tuple[float, ...]) -> float:
        o = replace(self.opts, position_sigma_m=self.base_position_sigma_m * st["p"],
                    rotation_sigma_rad=self.base_rotation_sigma_rad * st["p"], pose_error=self.model_of(st))
        noise = _imu_noise(self.base_imu, st["g"], st["a"], st["gn"], st["an"])
        warm = self.warm
        try:
            # a random walk next to a solved candidate: one Gauss-Newton step from its optimum
            # (graph.evidence_step); solved: the pose models, whose candidates lie further apart, and
            # position-only streams, whose attitude (seen through positions alone) is less linear
            step = None
            if (pose_key == warm["pose"] and self.kf.quat_wxyz is not None and warm["init"] is not None
                    and warm["init"].values is not None):
                step = evidence_step(self.samples, self.kf, noise, self.T_imu_pose, o, warm["init"], self.basis,
                                     self.like.get(pose_key))
            if step is not None:
                ev, start, self.like[pose_key] = step
            else:
                sol = solve_window(self.samples, self.kf, noise, self.T_imu_pose, o, warm["init"],
                                   want_evidence=True, basis=self.basis)
                ev, start = sol.log_evidence, WindowInit(gravity_unit=sol.gravity_unit, bias=sol.bias,
                                                         values=sol.values)
            if self.within is not None:  # fused keyframes: the samples' scatter about them
                ev += self.within.log_likelihood(o.position_sigma_m, o.rotation_sigma_rad)
            if ev > warm["ev"]:
                warm.update(ev=ev, init=start, pose=pose_key)
            return ev
        except Exception as exc:  # a diverged candidate is simply not chosen
            log.debug("noise candidate %s failed: %s", st, exc, exc_info=True)
            return float("-inf")

    def search(self, state: dict[str, float], chosen: dict[str, float], name: str, grid: list[float]) -> None:
        """Bracketing search along one coordinate, updating ``state`` and ``chosen`` in place.

        Starts at the current value's grid neighbours and walks uphill until the best point has
        evaluated neighbours on both sides (or is at the grid edge); then a parabola in log-scale.
        On a unimodal evidence curve this returns what the full grid would, at 3-4 instead of 6-7
        solves. A coordinate is searched at the others' best grid points (already evaluated: its
        search starts there without a new solve), not at their parabolas' vertices, which lie within
        half a grid step of them. The pose sigma, which trades off against both random walks, is
        fixed at its vertex before they are searched.
        """
        grid = sorted(grid)
        n = len(grid)
        i0 = _grid_index(grid, state[name])
        evs: dict[int, float] = {}

        def at(j: int) -> float:
            if j not in evs:
                evs[j] = self.evaluate({**state, name: grid[j]})
            return evs[j]

        for j in sorted(range(max(i0 - 1, 0), min(i0 + 1, n - 1) + 1), key=lambda j: abs(j - i0)):
            at(j)  # the current value first: the start of the warm-start chain
        while True:
            best = max(evs, key=lambda j: (evs[j], -abs(j - i0)))
            if best == min(evs) and best > 0:
                at(best - 1)
            elif best == max(evs) and best < n - 1:
                at(best + 1)
            else:
                break
        chosen[name] = _argmax_parabolic_log(grid, [evs.get(j, float("nan")) for j in range(n)])
        state[name] = chosen[name] if name == "p" else grid[max(evs, key=lambda j: evs[j])]


def estimate_noise(
    samples: MidpointSamples,
    kf: KeyframePoses,
    base_imu: ImuNoise,
    base_position_sigma_m: float,
    base_rotation_sigma_rad: float,
    T_imu_pose: np.ndarray,
    opts: SolveOptions,
    rw_scales: list[float],
    *,
    pose_scales: list[float] | None = None,
    estimate_pose: bool = True,
    estimate_gyro: bool = True,
    estimate_acc: bool = True,
    init: WindowInit | None = None,
    pose_error: PoseErrorGrid | None = None,
    density_scales: list[float] | None = None,
) -> NoiseChoice:
    """Coordinate-wise evidence maximisation (see the module docstring).

    With ``pose_error`` (6-DoF absolute streams), the correlated error's sigma and correlation
    time per axis group are coordinates too, searched before the random walks and once more after
    them (the two explain the same slow disagreement, as a bounded error or as a walking bias).
    With ``density_scales``, so are the accelerometer's and the gyro's white noise densities,
    searched first (a vibrating platform's white noise, far above the datasheet's, would otherwise
    be explained as a walking bias).
    """
    opts = replace(opts, compute_marginals=False, marginal_extras=False, reject_outliers=False, residuals=False)
    start_rw = 10.0 if 10.0 in rw_scales else rw_scales[len(rw_scales) // 2]
    state = {"g": start_rw if estimate_gyro else 1.0, "a": start_rw if estimate_acc else 1.0, "p": 1.0,
             "rs": 0.0, "rt": 1.0, "ps": 0.0, "pt": 1.0, "gn": 1.0, "an": 1.0}
    ev = _EvidenceSearch(samples, kf, base_imu, base_position_sigma_m, base_rotation_sigma_rad, T_imu_pose, opts,
                         init, pose_error, state)
    chosen = dict(state)
    if estimate_pose:
        ev.search(state, chosen, "p", list(pose_scales or POSE_SCALES))
    passes = 2 if pose_error is not None or density_scales is not None else 1

    def coordinate_passes() -> None:
        for _ in range(passes):
            if pose_error is not None:
                for group in ("r", "p"):
                    ev.search(state, chosen, group + "s", list(pose_error.sigma_scales))
                    if state[group + "s"] > 0:
                        ev.search(state, chosen, group + "t", list(pose_error.taus_s))
            if density_scales is not None:
                ev.search(state, chosen, "an", list(density_scales))
                ev.search(state, chosen, "gn", list(density_scales))
            if estimate_gyro:
                ev.search(state, chosen, "g", list(rw_scales))
            if estimate_acc:
                ev.search(state, chosen, "a", list(rw_scales))

    coordinate_passes()
    # A second start at the calibration's own values (every IMU factor 1x): a calibration written by
    # an earlier search holds that search's optimum, which a walk started at start_rw can pass by
    # for a local optimum. The search continues from whichever start has the higher evidence.
    home = {**state, "g": 1.0, "a": 1.0, "gn": 1.0, "an": 1.0}
    if (start_rw != 1.0 and home != state and 1.0 in rw_scales
            and (density_scales is None or 1.0 in density_scales) and ev.evaluate(home) > ev.evaluate(state)):
        log.info("noise search: the calibration's own values have the higher evidence; searching again from there")
        state.update(home)
        chosen.update(home)
        coordinate_passes()
    for name in ("rs", "rt", "ps", "pt", "gn", "an"):
        chosen[name] = state[name]  # grid points: these coordinates are not interpolated
    noise = _imu_noise(base_imu, chosen["g"], chosen["a"], chosen["gn"], chosen["an"])
    model = ev.model_of(chosen)
    log.info("noise by evidence: gyro rw x%.3g, acc rw x%.3g, gyro / acc density x%.3g / x%.3g, pose sigma x%.3g, "
             "correlated error %s (%d candidates)", chosen["g"], chosen["a"], chosen["gn"], chosen["an"], chosen["p"],
             None if model is None else model.to_dict(), len(ev.table))
    return NoiseChoice(noise, base_position_sigma_m * chosen["p"], base_rotation_sigma_rad * chosen["p"],
                       chosen["g"], chosen["a"], chosen["p"], NoiseEstimation.EVIDENCE, ev.table,
                       pose_error=model if model is not None and model.active else None,
                       gyro_density_scale=chosen["gn"], acc_density_scale=chosen["an"])

def grid_edge_warnings(choice: NoiseChoice, kind: PoseSourceKind, config: RecoveryConfig) -> tuple[str, ...]:
    """Warnings for evidence searches that ended on an edge of their candidate grid."""
    out = []
    grid = config.random_walk_scales
    for sensor, scale in (("gyro", choice.gyro_rw_scale), ("acc", choice.acc_rw_scale)):
        bound = (f"{sensor} random walk: the evidence search hit its bound ({scale:g}x the calibration; "
                 f"random_walk_scales spans {min(grid):g}x-{max(grid):g}x). ")
        if scale >= max(grid):
            out.append(bound + "Either the calibration's random walk is far off or the pose stream has artefacts the "
                       "bias would absorb; widen random_walk_scales only if the calibration is known to be wrong")
        elif scale <= min(grid):
            out.append(bound + "The bias drifts less than the calibration's random walk allows (datasheet walks are "
                       "upper limits): the bias is steadier, not less certain; judge it by the held-out blocks, and "
                       "lower random_walk_scales' smallest value to let the search go further")
    grid = config.pose_sigma_scales
    # a fixed pose sigma is not searched; smoothed ground-truth poses legitimately hit the lower edge
    searched = config.position_sigma_m is None and kind != PoseSourceKind.GROUND_TRUTH
    if searched and (choice.pose_scale <= min(grid) or choice.pose_scale >= max(grid)):
        out.append(f"pose sigma scale {choice.pose_scale:g} is at the edge of its candidate grid "
                   "(pose_sigma_scales); widen the grid")
    return tuple(out)
