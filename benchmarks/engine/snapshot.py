"""A traced single run: what the sensor looked at, what it saw, the truth and the estimates.

The harness keeps only per-step numbers; a snapshot figure (paper Fig. "Snapshot of
simulations") needs the looks, the returns, the true states and the estimates with
their covariances. :func:`trace_run` keeps them from the harness's step loop
(:func:`~mttbench.benchmarks.engine.loop.play`), seeded as
:func:`~mttbench.benchmarks.engine.loop.run_job` seeds it, so the traced run is the same run
as the harness's rows for ``(scenario, tracker label, policy label, looks, seed)``.

:meth:`Trace.frames` flattens the trace into three tidy tables (looks, truth,
estimates) that the figure functions read and the reproduction writes as CSV.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd

from ...scenarios.spec import Scenario
from .loop import Job, play
from .specs import PolicySpec, TrackerSpec


@dataclass(frozen=True)
class StepTrace:
    """One step of a traced run.

    ``cells (L,)`` int64 looked-at cells (repeats allowed), ``returns (L,)`` bool,
    ``truth (n, 4)`` true states, ``est_states (m, 4)``, ``est_covs (m, 4, 4)`` or
    None, ``est_count`` the tracker's count estimate.
    """

    step: int
    cells: np.ndarray
    returns: np.ndarray
    truth: np.ndarray
    truth_ids: np.ndarray
    est_states: np.ndarray
    est_covs: np.ndarray | None
    est_count: float


@dataclass(frozen=True)
class Trace:
    """A whole traced run (see the module docstring)."""

    scenario: Scenario
    tracker_label: str
    policy_label: str
    seed: int
    steps: list[StepTrace]

    def frames(self) -> dict[str, pd.DataFrame]:
        """Four tidy tables of the trace.

        ``looks``: step, look (index within the step), cell, ix, iy, positive.
        ``truth``: step, target id, px, vx, py, vy.
        ``estimates``: step, index, count (the step's count estimate), px, vx, py, vy,
        and the position covariance ``cov_xx, cov_xy, cov_yy`` (NaN when the tracker
        gives none). ``counts``: step, count (the tracker's count estimate, also when it
        reports no states). Positions in workspace units.
        """
        nx = self.scenario.grid.nx
        looks, truth, est, counts = [], [], [], []
        for s in self.steps:
            looks.append(pd.DataFrame({
                "step": s.step, "look": np.arange(len(s.cells)), "cell": s.cells,
                "ix": s.cells % nx, "iy": s.cells // nx, "positive": s.returns.astype(bool)}))
            truth.append(pd.DataFrame({
                "step": s.step, "id": s.truth_ids, "px": s.truth[:, 0], "vx": s.truth[:, 1],
                "py": s.truth[:, 2], "vy": s.truth[:, 3]}))
            m = len(s.est_states)
            covs = s.est_covs if s.est_covs is not None else np.full((m, 4, 4), np.nan)
            est.append(pd.DataFrame({
                "step": s.step, "index": np.arange(m), "count": float(s.est_count),
                "px": s.est_states[:, 0], "vx": s.est_states[:, 1], "py": s.est_states[:, 2],
                "vy": s.est_states[:, 3], "cov_xx": covs[:, 0, 0], "cov_xy": covs[:, 0, 2],
                "cov_yy": covs[:, 2, 2]}))
            counts.append(pd.DataFrame({"step": [s.step], "count": [float(s.est_count)]}))
        return {name: pd.concat(parts, ignore_index=True).astype({"step": "int64"})
                for name, parts in (("looks", looks), ("truth", truth), ("estimates", est),
                                    ("counts", counts))}


def trace_run(scenario: Scenario, tracker: TrackerSpec, seed: int,
              policy: PolicySpec | None = None, looks_per_step: int | None = None,
              n_steps: int | None = None) -> Trace:
    """Run one ``(scenario, tracker, policy, looks, seed)`` and record every step.

    The run is :func:`~mttbench.benchmarks.engine.loop.play` with the harness's labels, so
    it is the same run as the harness's rows for that job. ``n_steps`` shortens the
    run (the truth of the first steps does not depend on the run length). Raises if
    the tracker cannot run the scenario.
    """
    job = Job(scenario, tracker, policy, looks_per_step, int(seed))
    playback = play(scenario, tracker.make(), int(seed),
                    policy=job.policy.make() if job.policy is not None else None,
                    looks_per_step=job.looks_per_step, tracker_label=tracker.label,
                    policy_label=job.policy_label, n_steps=n_steps)
    steps = []
    for rec in playback:
        est = rec.estimate
        states = np.asarray(est.states, dtype=float).reshape(-1, 4)
        covs = None if est.covariances is None else np.asarray(est.covariances, dtype=float)
        steps.append(StepTrace(rec.k, np.asarray(rec.looks.cells, dtype=np.int64).copy(),
                               np.asarray(rec.looks.returns, dtype=bool).copy(),
                               rec.truth.copy(), rec.truth_ids.copy(), states.copy(), covs,
                               float(est.count)))
    return Trace(scenario, tracker.label, job.policy_label, int(seed), steps)
