"""The statistics the data diagnostics threshold (ccl_cli/diagnostics.py), measured on
moving, noise-free, noisy and at-rest simulations. One JSON object per line:

    python benchmarks/diagnostics_thresholds.py [--seeds 3]
"""

from __future__ import annotations

import argparse
import json

import numpy as np

from ccl_cli import diagnostics as D
from ccl_cli import simulate as sim
from ccl_cli.dataset import Demonstrations
from ccl_cli.io.derivative import local_polynomial_derivative


def tracker_at_rest(noise: float, rate: float = 50.0, duration: float = 60.0,
                    seed: int = 0) -> Demonstrations:
    """A finger resting on the table: constant position + white noise, velocity derived."""
    rng = np.random.default_rng(seed)
    n = int(duration * rate)
    X = np.array([0.30, -0.05, 0.12]) + rng.normal(scale=noise, size=(n, 3))
    t = np.arange(n) / rate
    demo = np.zeros(n, int)
    return Demonstrations(X=X, U=local_polynomial_derivative(t, X, demo), demo=demo, t=t,
                          metadata={"derivative": {"window": 9, "order": 2}})


def cases(seed: int):
    for noise in (0.0, 2e-4, 1e-3, 2e-3):
        yield f"tracker_plane noise={noise}", sim.tracker_plane(noise=noise, seed=seed)
        yield f"tracker_sphere noise={noise}", sim.tracker_sphere(noise=noise, seed=seed)
    yield "tracker_plane 500Hz window=9 noise=1e-3", sim.tracker_plane(rate=500.0, window=9, duration=30.0,
                                                                     seed=seed)
    yield "tracker_plane 500Hz noise=1e-3", sim.tracker_plane(rate=500.0, duration=30.0, seed=seed)
    for noise in (2e-4, 1e-3, 2e-3):
        yield f"tracker at rest noise={noise}", tracker_at_rest(noise, seed=seed)
    yield "arm_at_rest", sim.arm_at_rest(seed=seed)
    yield "arm_at_rest quiet velocities", sim.arm_at_rest(noise=1e-4, seed=seed)
    yield "toy2d trajectories", sim.toy2d(seed=seed)
    yield "toy2d uniform", sim.toy2d(sampling="uniform", n_samples=1000, n_demos=10, task=True, seed=seed)
    yield "two_link", sim.two_link(seed=seed)
    yield "arm7", sim.arm7(seed=seed)
    yield "varying_constraint snr 20 dB", sim.varying_constraint(snr_db=20.0, seed=seed)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seeds", type=int, default=3)
    args = ap.parse_args()
    for seed in range(args.seeds):
        for name, data in cases(seed):
            lv = D.noise_levels(data)
            codes = sorted({w["code"] for w in D.check_data(data)})
            print(json.dumps({"case": name, "seed": seed, "snr_u": round(lv["snr_u"], 3),
                              "snr_x": round(lv["snr_x"], 3), "band_x": round(lv["band_x"], 5),
                              "warnings": codes}))


if __name__ == "__main__":
    main()
