"""A pose graph that grows keyframe by keyframe in GTSAM's iSAM2, each loop closure gated as it comes.

GNC is a batch method (each of its steps solves the whole graph again), so online the loop closures the gate
accepts get a robust kernel instead (Cauchy by default: on City10000 DCS with Φ = 1 left even true closures
unused, the odometry's drift making every whitened residual large); odometry stays least squares. Every decision is
kept (:attr:`OnlineGraph.decisions`), so the closures can be labelled again and the gate certified again from them
as the map grows (:meth:`OnlineGraph.batch`, then ``label --by back-end`` and the audit of ``calibrate``).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from vpr_uncertainty.slam.pose_graph import KERNELS, gtsam_module

__all__ = ["OnlineGraph"]


class OnlineGraph:
    """Keyframes, odometry and gated loop closures, optimised incrementally by iSAM2.

    Parameters
    ----------
    gate : object or None
        Has ``__call__(row) -> bool`` and ``probability_correct`` (a :class:`~vpr_uncertainty.Gate`); None accepts
        every closure.
    dimension : {2, 3}
    robust : {"cauchy", "huber", "dcs", "none"}, default="cauchy"
        The kernel of the accepted closures (:data:`~vpr_uncertainty.slam.pose_graph.KERNELS`).
    first_pose : sequence of float, optional
        ``x y θ`` or ``x y z qx qy qz qw`` of the first keyframe (the origin by default), held by a prior.

    Examples
    --------
    >>> import numpy as np
    >>> graph = OnlineGraph(gate=None)
    >>> information = np.diag([100.0, 100.0, 400.0])
    >>> for i in range(1, 4):
    ...     graph.add_odometry(i - 1, i, [1.0, 0.0, np.pi / 2], information)
    ...     graph.update()
    >>> graph.add_closure(3, 0, [1.0, 0.0, np.pi / 2], information, scores=[0.9, 0.2])
    True
    >>> graph.update()
    >>> np.round(graph.estimate().atPose2(3).translation(), 6).tolist()
    [0.0, 1.0]
    """

    def __init__(self, gate: Any = None, *, dimension: int = 2, robust: str = "cauchy", first_pose: Any = None) -> None:
        gtsam = self._gtsam = gtsam_module()
        if dimension not in (2, 3) or robust not in ("none", *KERNELS):
            raise ValueError(f"dimension must be 2 or 3 and robust one of none, {', '.join(KERNELS)}")
        self.gate, self.dimension = gate, dimension
        self._kernel = None
        if robust != "none":
            self._kernel = getattr(gtsam.noiseModel.mEstimator, KERNELS[robust][0]).Create(KERNELS[robust][1])
        self._isam = gtsam.ISAM2(gtsam.ISAM2Params())
        self._new, self._guess = gtsam.NonlinearFactorGraph(), gtsam.Values()
        self._all = gtsam.NonlinearFactorGraph()  # every factor added: the batch problem of the same decisions
        first = (gtsam.Pose2() if dimension == 2 else gtsam.Pose3()) if first_pose is None else self._pose(first_pose)
        prior = gtsam.PriorFactorPose2 if dimension == 2 else gtsam.PriorFactorPose3
        self._add(prior(0, first, gtsam.noiseModel.Isotropic.Sigma(3 * dimension - 3, 1e-6)))
        self._guess.insert(0, first)
        #: ``(i, j, accepted, P(correct))`` of every closure, in the order they came.
        self.decisions: list[tuple[int, int, bool, float]] = []

    def _pose(self, values: Any) -> Any:
        gtsam, values = self._gtsam, np.asarray(values, dtype=np.float64)
        if len(values) != (3 if self.dimension == 2 else 7) or not np.isfinite(values).all():
            raise ValueError(f"a {self.dimension}-D pose is x y θ or x y z qx qy qz qw, finite, got {values.tolist()}")
        if self.dimension == 2:
            return gtsam.Pose2(*values)
        x, y, z, qx, qy, qz, qw = values
        return gtsam.Pose3(gtsam.Rot3.Quaternion(qw, qx, qy, qz), np.array([x, y, z]))

    def _factor(self, i: int, j: int, measurement: Any, information: Any, robust: bool) -> Any:
        gtsam = self._gtsam
        order = [0, 1, 2] if self.dimension == 2 else [3, 4, 5, 0, 1, 2]  # g2o order: translation first
        information = np.asarray(information, dtype=np.float64)[np.ix_(order, order)]
        noise = gtsam.noiseModel.Gaussian.Information(information)
        if robust and self._kernel is not None:
            noise = gtsam.noiseModel.Robust.Create(self._kernel, noise)
        factor = gtsam.BetweenFactorPose2 if self.dimension == 2 else gtsam.BetweenFactorPose3
        return factor(int(i), int(j), self._pose(measurement), noise)

    def _add(self, factor: Any) -> None:
        self._new.add(factor)
        self._all.add(factor)

    def add_odometry(self, i: int, j: int, measurement: Any, information: Any) -> None:
        """Odometry from keyframe ``i`` (known) to ``j``; a new ``j`` starts at pose i ∘ measurement."""
        factor = self._factor(i, j, measurement, information, robust=False)
        self._add(factor)
        if not (self._guess.exists(j) or self._isam.valueExists(j)):
            if self._guess.exists(i):
                start = self._guess.atPose2(i) if self.dimension == 2 else self._guess.atPose3(i)
            else:
                start = (
                    self._isam.calculateEstimatePose2(i)
                    if self.dimension == 2
                    else self._isam.calculateEstimatePose3(i)
                )
            self._guess.insert(j, start.compose(factor.measured()))

    def add_closure(self, i: int, j: int, measurement: Any, information: Any, *, scores: Any) -> bool:
        """A loop closure between known keyframes, added (with the robust kernel) when the gate accepts its VPR
        score row ``scores`` (K,); returns the decision."""
        row = np.asarray(scores, dtype=np.float64)
        accepted = True if self.gate is None else bool(self.gate(row))
        p = float("nan") if self.gate is None else float(self.gate.probability_correct(row[None])[0])
        self.decisions.append((int(i), int(j), accepted, p))
        if accepted:
            self._add(self._factor(i, j, measurement, information, robust=True))
        return accepted

    def update(self) -> None:
        """One iSAM2 step with what was added since the last (:meth:`estimate` reads the poses)."""
        self._isam.update(self._new, self._guess)
        self._new, self._guess = self._gtsam.NonlinearFactorGraph(), self._gtsam.Values()

    def estimate(self) -> Any:
        """The current poses (``gtsam.Values``): every keyframe's, so call it when needed, not every step."""
        return self._isam.calculateEstimate()

    def batch(self) -> Any:
        """Every factor added so far (the same decisions and kernel, the prior included): the batch problem to
        compare with, or to label the closures by."""
        return self._all.clone()
