"""Solve the exported eyekey problem with SciPy's L-BFGS-B and report the time to reach eyekey's optimum.

Usage: python3 benches/scipy_lbfgsb.py DIR   (DIR written by `eyekey bench --section solver --export DIR`)

Objective (same as eyekey's MultiplexObjective): f(x) = ||A x - b||^2 + mu * ||x||^2 / n, 0 <= x <= 1, x0 = 0.5.
Prints JSON with the time and evaluations L-BFGS-B needed to reach f* (1 + 1e-3), where f* is eyekey's optimum;
it stops there, or after a wall-time cap (second argument, seconds, default 600).
"""
import json
import sys
import time

import numpy as np
import scipy.io
import scipy.optimize


class Done(Exception):
    """Raised inside the objective to stop L-BFGS-B once the target is reached or time runs out."""


def main(d, cap_seconds=600.0):
    meta = json.load(open(f"{d}/problem.json"))
    ours = json.load(open(f"{d}/eyekey_result.json"))
    a = scipy.io.mmread(f"{d}/A.mtx").tocsr().astype(np.float64)
    at = a.T.tocsr()
    b = np.loadtxt(f"{d}/b.txt")
    n = a.shape[1]
    mu = meta["tikhonov_mean_square"] / n
    target = ours["f_star"] * (1 + 1e-3)
    state = {"evals": 0, "hit": None, "best": np.inf}
    t0 = time.perf_counter()

    def fg(x):
        r = a @ x - b
        f = float(r @ r + mu * (x @ x))
        g = 2.0 * (at @ r) + 2.0 * mu * x
        state["evals"] += 1
        state["best"] = min(state["best"], f)
        if state["hit"] is None and f <= target:
            state["hit"] = (time.perf_counter() - t0, state["evals"])
            raise Done()
        if time.perf_counter() - t0 > cap_seconds:
            raise Done()
        return f, g

    message = "stopped at the target"
    try:
        res = scipy.optimize.minimize(
            fg, np.full(n, 0.5), jac=True, method="L-BFGS-B", bounds=[(0.0, 1.0)] * n,
            options={"maxiter": 20000, "maxfun": 40000, "ftol": 1e-15, "gtol": 1e-12, "maxcor": 10},
        )
        message = str(res.message)
    except Done:
        if state["hit"] is None:
            message = f"not reached within the {cap_seconds:.0f} s cap"
    total = time.perf_counter() - t0
    out = {
        "scipy_version": scipy.__version__,
        "rows": a.shape[0], "cols": n, "nnz": a.nnz,
        "eyekey_f_star": ours["f_star"], "eyekey_seconds_to_1e-3": ours["seconds_to_1e-3"],
        "scipy_final_f": float(state["best"]), "scipy_total_seconds": total, "scipy_evaluations": state["evals"],
        "scipy_seconds_to_1e-3": state["hit"][0] if state["hit"] else None,
        "scipy_evaluations_to_1e-3": state["hit"][1] if state["hit"] else None,
        "scipy_message": message,
    }
    if out["scipy_seconds_to_1e-3"]:
        out["ratio_scipy_over_eyekey"] = out["scipy_seconds_to_1e-3"] / ours["seconds_to_1e-3"]
    print(json.dumps(out, indent=1))


if __name__ == "__main__":
    main(sys.argv[1], float(sys.argv[2]) if len(sys.argv) > 2 else 600.0)
