"""Which arm `tmscal selfcal identify` writes, by form, over seeds (docs/selfcal.md, "Running it"):
the one kinematic estimator with wrench rows only (``--form map``, the default), the paper's
kept-columns fit (``--form kept``) and the study's MAP model of every ArmModel parameter
(``tmscal.calib.selfcal.study.compare.canonical``, what ``--form map`` wrote before the
estimator took it over), against the nominal arm.

    .venv/bin/python benchmarks/selfcal_forms.py [--seeds 10] [--k 60] [--arm ur5e]

Per seed: a true arm with every geometric parameter in error (``tmscal.sim.arm.make_arm(arm,
"all", 100 + seed)``: ±2 mm / ±1°, what a lab has), ``--k`` configurations within ±0.8 rad of
the arm's home, their gravity wrenches with the noise of 100 averaged readings of the mock ATI
sensor (0.033 N, 0.0066 N·m per channel); validation on 200 other configurations within
±0.5 rad. Printed per form, means over seeds: the flange position error against the true arm
(mm, the "arm TCP" of benchmarks/selfcal_rig.py), the same after a hand/eye calibration
absorbs a rigid base transform and a TCP offset (``absorbed_errors``), and the held-out wrench
RMS (N). Takes a few seconds.
"""

from __future__ import annotations

import argparse

import numpy as np
from figures import record

from tmscal.calib.selfcal.estimate import estimate_from_wrenches
from tmscal.calib.selfcal.identify import identifiable, identify, position_errors
from tmscal.calib.selfcal.model import jacobian, wrench
from tmscal.calib.selfcal.study.compare import absorbed_errors, canonical
from tmscal.sim.arm import make_arm

SIGMA = np.array([0.033] * 3 + [0.0066] * 3)
FORMS = ("nominal", "map (estimator)", "kept (paper)", "canonical (study MAP)")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", type=int, default=10)
    ap.add_argument("--k", type=int, default=60)
    ap.add_argument("--arm", default="ur5e")
    a = ap.parse_args()
    out: dict[str, list[tuple[float, float, float]]] = {f: [] for f in FORMS}
    for seed in range(a.seeds):
        pair = make_arm(a.arm, "all", 100 + seed)
        rng = np.random.default_rng(seed)
        q = np.array(pair.home_q) + rng.uniform(-0.8, 0.8, (a.k, pair.nominal.n_joints))
        w = wrench(pair.true, q) + rng.normal(size=q.shape[:1] + (6,)) * SIGMA
        est = estimate_from_wrenches(pair.nominal, q, w, SIGMA)
        ident = identifiable(jacobian(pair.nominal, q) / np.tile(SIGMA, len(q))[:, None],
                             pair.nominal.parameter_names())
        kept = identify(pair.nominal, q, w, SIGMA, ident)
        can = canonical(pair.nominal, q, w, SIGMA, start=kept.model)
        qv = np.array(pair.home_q) + rng.uniform(-0.5, 0.5, (200, pair.nominal.n_joints))
        wv = wrench(pair.true, qv)
        for form, m in zip(FORMS, (pair.nominal, est.model, kept.model, can), strict=True):
            out[form].append((float(position_errors(pair.true, m, qv).mean()),
                              float(absorbed_errors(pair.true, m, qv).mean()),
                              float(np.sqrt(np.mean((wrench(m, qv)[:, :3] - wv[:, :3]) ** 2)))))
    print(f"arm {a.arm}, errors 'all', {a.seeds} seeds, {a.k} configurations; means over seeds")
    print(f"  {'form':<24}{'arm TCP mm':>12}{'after hand/eye mm':>19}{'wrench RMS N':>14}")
    fig: dict[str, float] = {}
    for form, rows in out.items():
        tcp, absorbed, rms = np.mean(rows, axis=0)
        print(f"  {form:<24}{tcp:>12.3f}{absorbed:>19.3f}{rms:>14.4f}")
        key = form.split()[0]
        fig.update({f"{key}_tcp_mm": round(float(tcp), 3),
                    f"{key}_absorbed_mm": round(float(absorbed), 3),
                    f"{key}_wrench_rms_n": round(float(rms), 4)})
    record("selfcal_forms", fig)


if __name__ == "__main__":
    main()
