"""`identify`: the payload's ten inertial parameters (and the joints' friction) from a joint log.

1. Zero-phase low-pass (Butterworth, forward and backward) of velocities and torques with the
   same filter, so they stay in phase; accelerations are the filtered velocities' derivative.
2. ``tau - tau_arm(q, v, a) = Y(q, v, a) phi + F(v) f``: the payload regressor from Drake's inverse
   dynamics (:mod:`real2sim.identify.regressor`) and Coulomb + viscous friction per joint.
3. Weighted least squares (each joint's rows scaled by its residual's spread from a first,
   unweighted pass), solved as a semidefinite program with Drake's MathematicalProgram and an
   open solver (Clarabel by default, or SCS): the 4x4 pseudo-inertia of ``phi`` is positive
   semidefinite (physically consistent: some mass distribution has these parameters), friction is
   non-negative, and, given the object's shape, all its mass lies inside the shape's bounding
   ellipsoid and a weak prior pulls towards the uniform-density estimate: parameters the data
   resolve do not feel it, the ones it cannot resolve fall back to it instead of to nonsense.
4. Standard errors from the weighted residual and the regressor: the usual least-squares
   covariance, without the constraints, widened for the rows' correlation (rows every 10 ms of a
   signal low-passed at 8 Hz are not independent: about one in ``rate / (2 cutoff)`` is; without it
   the errors read 2-3.5 times too small against the spread over repeated noise draws).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from real2sim.plumbing.errors import UserInputError
from real2sim.formats.joint_log import JointLog
from real2sim.identify.arm import ArmWithPayload, properties_from_phi
from real2sim.identify.regressor import friction_regressor, payload_regressor

PARAMETER_NAMES = ("mass_kg", "first_moment_x_kg_m", "first_moment_y_kg_m", "first_moment_z_kg_m",
                   "inertia_xx_kg_m2", "inertia_yy_kg_m2", "inertia_zz_kg_m2", "inertia_xy_kg_m2",
                   "inertia_xz_kg_m2", "inertia_yz_kg_m2")
#: Worst condition number of the column-scaled payload regressor at which every parameter still
#: counts as excited.
MAX_CONDITION = 1e3
#: The parallel low-pass of the regressor and the torques, Hz, and the speed below which a joint's rows
#: (with the filter's reach, about a period of it, around them) are left out, rad/s.
CUTOFF_HZ = 8.0
MIN_SPEED_RAD_PER_S = 0.1


@dataclass(frozen=True)
class ShapePrior:
    """What the object's geometry says, in its mesh frame: a bounding ellipsoid ``{x: (x - c)^T E
    (x - c) <= 1}`` and the uniform-density parameters ``phi``; ``size_m`` its longest side."""

    ellipsoid_centre_m: np.ndarray
    ellipsoid_matrix: np.ndarray
    uniform_phi: np.ndarray
    size_m: float


@dataclass(frozen=True)
class Identification:
    """The result, object (mesh) frame. ``phi``: (10,); ``standard_errors``: (10,) of phi;
    ``friction_coulomb_n_m``, ``friction_viscous_n_m_s``: per joint; ``residual_rms_n_m``: per joint;
    ``condition_number``: of the column-scaled payload regressor; ``samples``: rows used per joint."""

    phi: np.ndarray
    standard_errors: np.ndarray
    friction_coulomb_n_m: np.ndarray
    friction_viscous_n_m_s: np.ndarray
    residual_rms_n_m: np.ndarray
    condition_number: float
    samples: int
    solver: str

    @property
    def mass_kg(self) -> float:
        return float(self.phi[0])

    def properties(self) -> tuple[float, np.ndarray, np.ndarray]:
        """(mass kg, CoM m, inertia about the CoM kg m^2)."""
        return properties_from_phi(self.phi)


def _lowpass(x: np.ndarray, dt_s: float, cutoff_hz: float) -> np.ndarray:
    from scipy.signal import butter, sosfiltfilt

    sos = butter(4, cutoff_hz, fs=1.0 / dt_s, output="sos")
    return sosfiltfilt(sos, x, axis=0)


def prepared_signals(log: JointLog, rate_hz: float = 250.0, cutoff_hz: float = 40.0):
    """(q, v, a, tau, dt_s) lightly low-passed (``cutoff_hz``, zero phase) and decimated to about
    ``rate_hz``: the regressor is built on these, and then filtered again with the torques
    (:func:`identify`): the friction's sign changes make the regressor nonlinear in the signals, so
    filtering the torques alone would leave them out of step with it."""
    dt = float(np.median(np.diff(log.time_s)))
    if not np.allclose(np.diff(log.time_s), dt, rtol=1e-3, atol=1e-9):
        raise UserInputError("the log's samples must be evenly spaced in time")
    cutoff = min(cutoff_hz, 0.4 / dt)
    v = _lowpass(log.v_rad_per_s, dt, cutoff)
    a = _lowpass(log.a_rad_per_s2, dt, cutoff) if log.a_rad_per_s2 is not None else np.gradient(v, dt, axis=0)
    tau = _lowpass(log.tau_n_m, dt, cutoff)
    stride = max(1, int(round(1.0 / (rate_hz * dt))))
    return log.q_rad[::stride], v[::stride], a[::stride], tau[::stride], dt * stride


def identify(arm: ArmWithPayload, log: JointLog, *, shape: ShapePrior | None = None, solver: str = "clarabel",
             cutoff_hz: float = CUTOFF_HZ, rate_hz: float = 100.0, trim_s: float = 0.25,
             signal_cutoff_hz: float = 40.0, min_speed_rad_per_s: float = MIN_SPEED_RAD_PER_S,
             physical: bool = True) -> Identification:
    """Identify the payload of ``arm`` (loaded with ``log``'s grasp) from ``log``: the regressor and the
    torques low-passed alike at ``cutoff_hz`` (zero phase), ``trim_s`` of filter transients cut at
    each end, rows decimated to about ``rate_hz``. ``physical=False``: plain weighted least squares
    without the constraints and the prior (for comparison only: it may return a negative mass or
    inertia)."""
    if log.num_joints != arm.num_joints:
        raise UserInputError(f"the log has {log.num_joints} joints, the robot model {arm.num_joints}")
    duration = float(log.time_s[-1] - log.time_s[0])
    n = arm.num_joints
    if duration * rate_hz < 4 * (10 + 2 * n) or duration < 4 * trim_s:
        raise UserInputError(f"the log is too short to excite every parameter ({len(log.time_s)} samples over "
                             f"{duration:.2f} s; an exciting trajectory takes about 10 s)")
    q, v, a, tau, dt = prepared_signals(log, cutoff_hz=signal_cutoff_hz)
    tau_arm, y = payload_regressor(arm, q, v, a)
    f = friction_regressor(v)
    # the same zero-phase filter on both sides of tau - tau_arm = Y phi + F f
    both = _lowpass(np.concatenate([(tau - tau_arm)[..., None], y, f], axis=2), dt, cutoff_hz)
    row_stride = max(1, int(round(1.0 / (rate_hz * dt))))
    rows_kept = np.arange(int(np.ceil(trim_s / dt)), len(q) - int(np.ceil(trim_s / dt)), row_stride)
    b, y, f = both[rows_kept, :, 0], both[rows_kept, :, 1:11], both[rows_kept, :, 11:]
    # Near a velocity reversal the friction model (a smoothed sign) is least true and the filter
    # smears its error: those rows are left out, joint by joint.
    moving = _moving(v, dt, min_speed_rad_per_s, cutoff_hz)[rows_kept]
    q = q[rows_kept]
    scaled = y.reshape(-1, 10) / np.linalg.norm(y.reshape(-1, 10), axis=0).clip(1e-12)
    sv = np.linalg.svd(scaled, compute_uv=False)
    condition = float(sv[0] / max(sv[-1], 1e-15))
    if condition > MAX_CONDITION and shape is None:
        raise UserInputError(f"the log does not excite every inertial parameter (condition number {condition:.3g}); "
                             "use an exciting trajectory (real2sim excite) or pass --shape ASSETDIR")
    a_mat = np.concatenate([y, f], axis=2) * moving[..., None]  # (T, n, 10 + 2n); rows left out are 0
    b = b * moving
    # first pass: each joint's residual spread, for the weights of the second
    x0, *_ = np.linalg.lstsq(a_mat.reshape(-1, a_mat.shape[2]), b.reshape(-1), rcond=None)
    sigma = np.sqrt(np.sum((a_mat @ x0 - b) ** 2, axis=0) / moving.sum(axis=0).clip(1)).clip(1e-6)
    rows = (a_mat / sigma[None, :, None]).reshape(-1, a_mat.shape[2])
    rhs = (b / sigma[None, :]).reshape(-1)
    x = (_constrained_least_squares(rows, rhs, n, shape, solver) if physical
         else np.linalg.lstsq(rows, rhs, rcond=None)[0])
    residual = a_mat @ x - b
    dof = max(1, int(moving.sum()) - rows.shape[1])
    s2 = float(np.sum((rows @ x - rhs) ** 2) / dof)
    row_rate_hz = 1.0 / (dt * row_stride)
    cov = s2 * max(1.0, row_rate_hz / (2.0 * cutoff_hz)) * np.linalg.pinv(rows.T @ rows)
    return Identification(
        phi=x[:10], standard_errors=np.sqrt(np.clip(np.diag(cov)[:10], 0, None)),
        friction_coulomb_n_m=x[10:10 + n], friction_viscous_n_m_s=x[10 + n:],
        residual_rms_n_m=np.sqrt(np.sum(residual ** 2, axis=0) / moving.sum(axis=0).clip(1)), condition_number=condition,
        samples=len(q), solver=solver)


def _moving(v: np.ndarray, dt: float, min_speed: float, cutoff_hz: float) -> np.ndarray:
    """(T, n) bool: the joint is at least ``min_speed`` from a reversal over the filter's reach
    (about one period of ``cutoff_hz``) around each sample."""
    from scipy.ndimage import minimum_filter1d

    reach = max(1, int(round(1.0 / (cutoff_hz * dt))))
    return minimum_filter1d(np.abs(v), size=2 * reach + 1, axis=0) >= min_speed


def _constrained_least_squares(rows: np.ndarray, rhs: np.ndarray, n: int, shape: ShapePrior | None,
                               solver: str) -> np.ndarray:
    """argmin |rows x - rhs|^2 (+ the shape's prior) subject to the constraints of the module docstring.

    The parameters span six orders of magnitude (a mass near 1 kg, inertias near 1e-4 kg m^2), which
    a solver's tolerances do not: it solves for ``w = x / d - x0 / d``, each parameter in units of its
    own size ``d`` (mass m, first moments m L, inertias m L^2, with m and L from the unconstrained
    minimum ``x0``) and centred there, and takes the pseudo-inertia in units of L and m (a congruence
    and a positive factor, which keep it semidefinite).
    """
    from pydrake.solvers import ClarabelSolver, MathematicalProgram, ScsSolver, SolverOptions

    p = rows.shape[1]
    hessian = rows.T @ rows
    gradient = -rows.T @ rhs
    if shape is not None:
        # a weak Gaussian prior on phi around the uniform-density estimate: std half its scale
        m = max(float(shape.uniform_phi[0]), 1e-6)
        size = max(shape.size_m, 1e-3)
        scale = np.array([m] + [m * size] * 3 + [m * size ** 2] * 6) * 0.5
        weight = 1.0 / scale ** 2
        hessian[:10, :10] += np.diag(weight)
        gradient[:10] -= weight * shape.uniform_phi
    x0 = np.linalg.lstsq(hessian, -gradient, rcond=None)[0]  # the unconstrained minimum
    # each parameter in units of its own size: mass m, first moments m L, inertias m L^2
    m = max(abs(float(x0[0])), 1e-3)
    length = float(np.clip(np.sqrt(abs(float(np.sum(x0[4:7]))) / (2.0 * m)), 0.01, 1.0))
    d = np.concatenate([[m], [m * length] * 3, [m * length ** 2] * 6, np.maximum(np.abs(x0[10:]), 1e-2)])
    q = d[:, None] * hessian * d[None, :]
    q = q / np.abs(np.diag(q)).max()
    # centred on the unconstrained minimum, so the cost is 1/2 w^T Q w: z = x / d = x0 / d + w
    z0 = x0 / d
    prog = MathematicalProgram()
    w = prog.NewContinuousVariables(p, "w")
    prog.AddQuadraticCost(q, np.zeros(p), w, is_convex=True)
    units = np.diag([1.0 / length] * 3 + [1.0])
    basis = [units @ f @ units / m * (d[i - 1] if i else 1.0) for i, f in enumerate(_pseudo_inertia_basis(p))]
    constant = sum(z0[i] * basis[i + 1] for i in range(p))
    prog.AddLinearMatrixInequalityConstraint([constant] + basis[1:], w)
    prog.AddBoundingBoxConstraint(-z0[10:], np.full(p - 10, np.inf), w[10:])
    if shape is not None:
        q_mat = _inside_ellipsoid(shape)
        coeffs = np.array([np.trace(q_mat @ f) for f in _pseudo_inertia_basis(p)[1:11]]) * d[:10]
        coeffs = coeffs / np.abs(coeffs).max()
        prog.AddLinearConstraint(coeffs[None, :], [-float(coeffs @ z0[:10])], [np.inf], w[:10])
    chosen = {"clarabel": ClarabelSolver, "scs": ScsSolver}.get(solver)
    if chosen is None:
        raise UserInputError(f"unknown solver {solver!r}: clarabel or scs")
    if _feasible(x0, shape):
        return x0  # the constraints are not active: the unconstrained minimum is the answer, exactly
    options = SolverOptions()
    if solver == "clarabel":
        for name in ("tol_gap_abs", "tol_gap_rel", "tol_feas"):
            options.SetOption(chosen.id(), name, 1e-10)
    result = chosen().Solve(prog, None, options)
    if not result.is_success():
        raise RuntimeError(f"the identification program did not solve ({result.get_solution_result()})")
    return d * (z0 + np.asarray(result.GetSolution(w)))


def _inside_ellipsoid(shape: ShapePrior) -> np.ndarray:
    """Q with ``tr(Q J) >= 0`` for a pseudo-inertia J whose mass lies in the shape's bounding
    ellipsoid ``(x - c)^T E (x - c) <= 1``: ``tr(Q J)`` integrates ``1 - (x - c)^T E (x - c)`` over
    the mass (Wensing et al., 2017)."""
    e, c = shape.ellipsoid_matrix, shape.ellipsoid_centre_m
    q_mat = np.zeros((4, 4))
    q_mat[:3, :3], q_mat[:3, 3], q_mat[3, :3], q_mat[3, 3] = -e, e @ c, e @ c, 1.0 - c @ e @ c
    return q_mat


def _feasible(x: np.ndarray, shape: ShapePrior | None) -> bool:
    """Whether ``x`` meets the constraints of :func:`_constrained_least_squares` (with a margin)."""
    from real2sim.identify.arm import pseudo_inertia

    j = pseudo_inertia(x[:10])
    if np.linalg.eigvalsh(j).min() < 1e-9 * max(float(x[0]), 1e-12) or np.any(x[10:] < 0):
        return False
    if shape is not None:
        return float(np.trace(_inside_ellipsoid(shape) @ j)) >= 0.0
    return True


def _pseudo_inertia_basis(p: int) -> list[np.ndarray]:
    """``[F0, F1, ..., Fp]`` with ``F0 + sum x_i F_i`` the pseudo-inertia of ``x[:10]`` (friction
    parameters get zero matrices)."""
    from real2sim.identify.arm import pseudo_inertia

    out = [np.zeros((4, 4))]
    for i in range(p):
        e = np.zeros(10)
        if i < 10:
            e[i] = 1.0
        out.append(pseudo_inertia(e) if i < 10 else np.zeros((4, 4)))
    return out
