"""Estimating an uneven other's body from its answers (issue 13; beyond thesis 3.3).

**The regressor.** A rigid body's joint torques are linear in its inertial parameters (the
classical robot-identification regressor, Atkeson, An & Hollerbach 1986): ``tau = Y(q, qd, qdd)
theta``. The self computes ``Y`` on its own body (:func:`self_regressor`), one column per
physical component of a body like its own, performing the motion as the other does (a joint
the other lacks held still):

* per moving link (upper arm, forearm, shin) its gravity torques and its inertial (velocity and
  acceleration) torques, separately: a link ``l`` times longer has ``l`` times the first moment
  and about ``l^2`` times the second; ``theta = 1`` is the self's own link;
* a point mass at the elbow (kg; a longer upper arm carries the forearm further out) and one
  in the hand (kg; a payload, a longer forearm);
* per joint viscous damping (``qd``, N m s/rad) and Coulomb friction (``tanh(qd / 0.05)``, N m).

The self's own body is ``theta_self`` (links 1, the rest 0); the thesis's proportional other is
``s * theta_self``.

**Answers as constraints.** Every open answer "word k" about motion ``m`` says
``g_max (k-1)/d <= F_conv(Y_m theta) < g_max k/d`` (eq. 3.4, 3.8). Every rule (eq. 3.8, f1-f4)
is positively homogeneous of degree 1 in the torques and piecewise linear, so around an
estimate each answer is a linear constraint on ``theta`` (:func:`g_and_gradient`); the set of
bodies every answer allows is an intersection of slabs, narrowed by each answer.

**The estimate** (:class:`BodyEstimate`) is the body nearest to a proportional one (``s`` free)
that satisfies the answers: regularised least squares (scipy ``least_squares``, bounds
``theta >= 0``) with a squared hinge on every violated bin and a weak pull to every bin's middle
(each distinct question counted once), re-linearised at every iteration. Noisy answers that
contradict each other are settled by the least squares.

**Probe motions** (:meth:`BodyEstimate.choose_probe`): a Gaussian approximation of the
remaining uncertainty (prior plus one linear measurement per answer, a bin's width being a
uniform's) predicts, for every candidate motion (each shared motion at several amplitudes and
speeds), a distribution over the words; the candidate whose answer is least predictable
(largest entropy) is asked: it cuts the set of bodies most.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares

from shared.clip import Clip
from shared.errors import BadInput

LINKS = ("upper_arm", "forearm", "shin")
POINTS = ("elbow", "hand")
JOINTS = ("shoulder_pitch", "shoulder_roll", "elbow", "knee")
SELF_MASS = 2.4


def _links(joints) -> list[str]:
    """The links that move the felt joints (the shin only moves the knee)."""
    return [link for link in LINKS if link != "shin" or "knee" in joints]


def column_names(joints) -> list[str]:
    names = [f"{link}.{part}" for link in _links(joints) for part in ("gravity", "inertial")]
    names += [f"{p}_mass" for p in POINTS if p in ("elbow", "hand") and any(j != "knee" for j in joints)]
    names += [f"damping.{j}" for j in joints] + [f"friction.{j}" for j in joints]
    return names


def theta_self(joints) -> np.ndarray:
    return np.array([1.0 if n.split(".")[0] in LINKS else 0.0 for n in column_names(joints)])


_MODELS: dict = {}


def _column_bodies(missing: tuple[str, ...]):
    """The self's body with one component at a time (cached: the self's body never changes)."""
    from shared.bodies.robot import LINK_SHARE, BodySpec, small_humanoid

    if missing not in _MODELS:
        bodies = {}
        for link in LINKS:
            bodies[link] = small_humanoid(BodySpec(mass=SELF_MASS, missing=list(missing)), name=f"self:{link}",
                                          link_masses={link: LINK_SHARE[link] * SELF_MASS})
        bodies["elbow_mass"] = small_humanoid(BodySpec(mass=SELF_MASS, elbow_mass=1.0, missing=list(missing)),
                                              name="self:elbow", link_masses={})
        bodies["hand_mass"] = small_humanoid(BodySpec(mass=SELF_MASS, payload=1.0, missing=list(missing)),
                                             name="self:hand", link_masses={})
        bodies["none"] = small_humanoid(BodySpec(mass=SELF_MASS, missing=list(missing)), name="self:none", link_masses={})
        _MODELS[missing] = bodies
    return _MODELS[missing]


def self_regressor(motion: Clip, joints, missing=()) -> np.ndarray:
    """``Y`` (T, len(joints), P) of ``motion`` on the self's body (columns: :func:`column_names`).
    ``missing``: joints the other lacks; the self holds them still (their channels are dropped)
    and feels nothing there (their rows are zero)."""
    from shared.bodies.body import _derivatives, _qpos_trajectory, coulomb, mj_inverse_series

    joints = list(joints)
    missing = tuple(sorted(set(missing)))
    bad = [j for j in joints if j not in JOINTS]
    if bad:
        raise BadInput(f"unknown joints {bad}; one of {', '.join(JOINTS)}", field="joints")
    keep = [c for c in motion.channels if c not in missing]
    motion = motion.with_data(motion.select(keep), channels=keep, groups={"motion": keep})
    bodies = _column_bodies(missing)
    ref = bodies["none"]
    q = _qpos_trajectory(ref, motion)
    v, a = _derivatives(ref.model, q, motion.fps)
    dof = {d.channel: d.dof for d in ref.dofs}
    rows = [dof.get(j) for j in joints]
    zero = np.zeros_like(v)

    def felt(tau):
        out = np.zeros((len(q), len(joints)))
        for k, r in enumerate(rows):
            if r is not None:
                out[:, k] = tau[:, r]
        return out

    base_full = mj_inverse_series(ref.model, q, v, a)[0]
    base_grav = mj_inverse_series(ref.model, q, zero, zero)[0]
    cols = []
    names = column_names(joints)
    for key in [*_links(joints), "elbow_mass", "hand_mass"]:
        m = bodies[key].model
        full = mj_inverse_series(m, q, v, a)[0] - base_full
        if key in LINKS:
            grav = mj_inverse_series(m, q, zero, zero)[0] - base_grav
            cols += [felt(grav), felt(full - grav)]
        elif key in names:
            cols.append(felt(full))
    for kind in ("damping", "friction"):
        for j in joints:
            c = np.zeros((len(q), len(joints)))
            if dof.get(j) is not None:
                vel = v[:, dof[j]]
                c[:, joints.index(j)] = vel if kind == "damping" else coulomb(vel)
            cols.append(c)
    return np.stack(cols, axis=-1)


def g_and_gradient(y: np.ndarray, theta: np.ndarray, rule: str = "eq3.8", tau_max: float = 1.0,
                   weights=None) -> tuple[float, np.ndarray]:
    """``g = F_conv(Y theta)`` (eq. 3.8, 3.13-3.16) and its gradient in ``theta`` (exact where
    no torque changes sign and no maximum changes place; ``g = gradient . theta`` there)."""
    tau = y @ theta
    w = np.ones(tau.shape[1]) if weights is None else np.asarray(weights, float)
    s = np.sign(tau) * w / tau_max  # d|tau_tj| w_j / tau_max
    a = np.abs(tau) * w / tau_max
    if rule in ("eq3.8", "f1"):
        g = a.sum(axis=1).mean() if rule == "eq3.8" else a.mean()
        grad = np.einsum("tj,tjp->p", s, y) / (len(tau) if rule == "eq3.8" else tau.size)
    elif rule == "f2":
        t = a.argmax(axis=0)
        j = np.arange(tau.shape[1])
        g = a[t, j].sum()
        grad = np.einsum("j,jp->p", s[t, j], y[t, j])
    elif rule == "f3":
        t = int(a.sum(axis=1).argmax())
        g = a[t].sum()
        grad = s[t] @ y[t]
    elif rule == "f4":
        t, j = np.unravel_index(int(a.argmax()), a.shape)
        g = a[t, j]
        grad = s[t, j] * y[t, j]
    else:
        raise BadInput(f"unknown conversion rule {rule!r}")
    return float(g), grad


@dataclass
class Answer:
    key: str  # the question: which motion, at which amplitude and speed
    y: np.ndarray  # its regressor on the self's body
    k: int


class BodyEstimate:
    """The other's body ``theta`` from its open answers (see module docstring).

    ``language``: a :class:`shared.estimation.conversation.Language` (d, g_max, tau_max, rule,
    weights, joints); ``scale_of``: regressors of the shared motions, which set each column's
    prior scale."""

    PRIOR = 1.0  # a component may differ from the proportional body by about a motion's whole g
    COUPLING = 0.5  # a link's inertial part stays within ~50 % of its gravity part (length ratio 0.5-1.5)
    HINGE = 30.0  # how much harder a violated bin counts than the pull to a bin's middle

    def __init__(self, language, shared: list[np.ndarray]):
        if not shared:
            raise BadInput("the body estimate needs the shared motions' regressors")
        self.language = language
        self.names = column_names(language.joints)
        self.theta_self = theta_self(language.joints)
        self.answers: list[Answer] = []
        # a column's typical effect on g per unit, over the shared motions (the prior's scale)
        eff = np.array([[self._g(y[..., p:p + 1], np.ones(1)) for p in range(y.shape[-1])] for y in shared]).mean(axis=0)
        g_self = float(np.mean([self._g(y, self.theta_self) for y in shared]))
        self.g_self = max(g_self, 1e-9)
        self.prior_sd = np.where(eff > 1e-12, self.PRIOR * self.g_self / np.maximum(eff, 1e-12), 1.0)
        self.theta = self.theta_self.copy()
        self.s = 1.0
        # (gravity, inertial) column pairs of one link: one mass, one length
        self.pairs = [(self.names.index(f"{link}.gravity"), self.names.index(f"{link}.inertial"))
                      for link in LINKS if f"{link}.gravity" in self.names]
        self.coupling = np.zeros((len(self.pairs), len(self.names)))
        for r, (i, j) in enumerate(self.pairs):
            self.coupling[r, i], self.coupling[r, j] = -1.0 / self.COUPLING, 1.0 / self.COUPLING

    def _g(self, y, theta) -> float:
        lang = self.language
        return g_and_gradient(y, theta, lang.rule, lang.tau_max, lang.weights)[0]

    def _grad(self, y, theta):
        lang = self.language
        return g_and_gradient(y, theta, lang.rule, lang.tau_max, lang.weights)

    def start(self, scale: float) -> None:
        """Start the least squares from the proportional body ``scale * theta_self``."""
        self.s = float(max(scale, 1e-3))
        self.theta = self.s * self.theta_self

    # ------------------------------------------------------------------ answers
    def add(self, key: str, y: np.ndarray, k: int) -> None:
        self.answers.append(Answer(key, np.asarray(y, float), int(k)))

    def _distinct(self) -> list[Answer]:
        seen, out = set(), []
        for a in self.answers:
            if (a.key, a.k) not in seen:
                seen.add((a.key, a.k))
                out.append(a)
        return out

    def fit(self) -> np.ndarray:
        """The estimate from every answer so far (``theta_self`` scaled, before any answer)."""
        answers = self._distinct()
        if not answers:
            return self.theta
        lang = self.language
        bounds = [lang.bounds(a.k) for a in answers]
        width = lang.g_max / lang.d
        mids = [(lo + hi) / 2 if np.isfinite(hi) else None for lo, hi in bounds]
        sd = width / np.sqrt(12.0)
        n_p = len(self.theta)

        def parts(x):
            theta, s = x[:n_p], x[n_p]
            res = [(theta - s * self.theta_self) / self.prior_sd, self.coupling @ theta / max(s, 0.1)]
            jac = [np.hstack([np.diag(1 / self.prior_sd), (-self.theta_self / self.prior_sd)[:, None]]),
                   np.hstack([self.coupling / max(s, 0.1), np.zeros((len(self.pairs), 1))])]
            for a, (lo, hi), mid in zip(answers, bounds, mids):
                g, grad = self._grad(a.y, theta)
                over = max(0.0, g - hi) if np.isfinite(hi) else 0.0
                under = max(0.0, lo - g)
                r = self.HINGE * (over - under) / sd
                jr = self.HINGE * grad / sd * (1.0 if over > 0 or under > 0 else 0.0)
                res.append(np.array([r, 0.0 if mid is None else (g - mid) / sd]))
                jac.append(np.vstack([np.r_[jr, 0.0], np.r_[grad / sd if mid is not None else 0 * grad, 0.0]]))
            return np.concatenate(res), np.vstack(jac)

        x0 = np.r_[self.theta, self.s]
        sol = least_squares(lambda x: parts(x)[0], x0, jac=lambda x: parts(x)[1], bounds=(0.0, np.inf),
                            method="trf", max_nfev=200, x_scale="jac")
        self.theta, self.s = sol.x[:n_p].copy(), float(sol.x[n_p])
        return self.theta

    def consistent(self) -> bool:
        """Whether the estimate puts every answer in its bin (within a tenth of a bin: the fit's
        hinge is soft)."""
        tol = 0.1 * self.language.g_max / self.language.d
        for a in self._distinct():
            lo, hi = self.language.bounds(a.k)
            g = self._g(a.y, self.theta)
            if g < lo - tol or g > hi + tol:
                return False
        return True

    def torques(self, y: np.ndarray) -> np.ndarray:
        """The other's estimated torques (T, joints) for a motion's regressor."""
        return np.asarray(y, float) @ self.theta

    # ------------------------------------------------------------------ probes
    def covariance(self) -> np.ndarray:
        """The Gaussian approximation of what the answers leave uncertain (see module docstring)."""
        prec = np.diag(1.0 / self.prior_sd ** 2)
        # the proportional direction is free in the prior: give it the spread of one bin
        u = self.theta_self / max(np.linalg.norm(self.theta_self), 1e-12)
        prec = prec - np.outer(prec @ u, prec @ u) / (u @ prec @ u) + np.outer(u, u) / (self.s + 1.0) ** 2
        prec = prec + self.coupling.T @ self.coupling / max(self.s, 0.1) ** 2
        sd = self.language.g_max / self.language.d / np.sqrt(12.0)
        for a in self._distinct():
            _, grad = self._grad(a.y, self.theta)
            prec += np.outer(grad, grad) / sd ** 2
        return np.linalg.pinv(prec)

    def choose_probe(self, candidates: dict[str, np.ndarray], asked=()) -> str | None:
        """The candidate (key -> regressor) whose answer is least predictable; ``None`` when
        every candidate's word is certain."""
        cov = self.covariance()
        lang = self.language
        edges = lang.g_max * np.arange(1, lang.d) / lang.d
        best, best_h = None, 1e-3
        from scipy.stats import norm

        for key, y in candidates.items():
            if key in asked:
                continue
            g, grad = self._grad(y, self.theta)
            sd = float(np.sqrt(max(grad @ cov @ grad, 1e-18)))
            cdf = norm.cdf((edges - g) / sd)
            p = np.diff(np.r_[0.0, cdf, 1.0])
            p = p[p > 1e-12]
            h = float(-(p * np.log(p)).sum())
            if h > best_h:
                best, best_h = key, h
        return best
