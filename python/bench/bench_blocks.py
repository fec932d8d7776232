"""Cost of ndr's building blocks called from Python, against filterpy and padasip.

Run from the repository root after ``pip install .`` (add ``filterpy`` and
``padasip`` to compare; each missing one is skipped):

    python python/bench/bench_blocks.py [--quick]

Measures, on the paper's triple-integrator model (T = 0.2 s, sigma_q = 1):

- one Kalman3 ``predict()`` + ``update(z)`` from Python, against filterpy's
  ``KalmanFilter`` with the same F, H, Q, R in the same process;
- a batch run over 100 000 samples (``ndr.kalman3_filter``) against
  filterpy's Python loop of ``predict()`` + ``update(z)``;
- one RLS ``adapt(d, x)`` (5 weights) and a 100 000-sample run
  (``ndr.rls_filter``) against padasip's ``FilterRLS``.

Per-call times are the best of several ``timeit`` repeats; batch times the
best of a few runs. Prints a markdown table, the machine and the command.
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
import timeit
from importlib import metadata

import numpy as np

import ndr

T = 0.2
SIGMA_Q = 1.0
N_BATCH = 100_000


def per_call(stmt: str, names: dict, number: int, repeat: int = 5) -> float:
    """Best time of one execution of the statement ``stmt``, in seconds."""
    return min(timeit.repeat(stmt, globals=names, number=number, repeat=repeat)) / number


def per_sample(fn, rows: int, repeat: int = 3) -> float:
    """Best time of ``fn()`` divided by ``rows``: a Python loop over samples."""
    return once(fn, repeat) / rows


def once(fn, repeat: int = 3) -> float:
    """Best wall time of ``fn()``, in seconds."""
    best = float("inf")
    for _ in range(repeat):
        t0 = timeit.default_timer()
        fn()
        best = min(best, timeit.default_timer() - t0)
    return best


def cpu_model() -> str:
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def filterpy_kalman():
    try:
        from filterpy.kalman import KalmanFilter
    except ImportError:
        return None
    kf = KalmanFilter(dim_x=3, dim_z=1)
    kf.F = np.array([[1.0, T, T * T / 2], [0.0, 1.0, T], [0.0, 0.0, 1.0]])
    kf.H = np.array([[1.0, 0.0, 0.0]])
    kf.Q = np.diag([0.0, 0.0, SIGMA_Q**2])
    kf.R = np.array([[SIGMA_Q**2]])
    kf.P = np.eye(3) * SIGMA_Q**2
    kf.x = np.zeros((3, 1))
    return kf


def padasip_rls(n: int):
    try:
        import padasip
    except ImportError:
        return None
    return padasip.filters.FilterRLS(n, mu=0.99, eps=1e-3, w="zeros")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="fewer iterations (a smoke run)")
    args = parser.parse_args()
    scale = 10 if args.quick else 1
    n_batch = N_BATCH // scale

    rng = np.random.default_rng(2001)
    z_series = 0.6 + np.cumsum(rng.normal(scale=0.01, size=n_batch))
    rows: list[tuple[str, str, str, str]] = []

    def us(t: float) -> str:
        return f"{t * 1e6:.3f} µs"

    def ms(t: float) -> str:
        return f"{t * 1e3:.1f} ms"

    samples = f"{n_batch:,}".replace(",", " ")

    # --- Kalman3, one step from Python.
    k = ndr.Kalman3(T, sigma_q=SIGMA_Q)
    names = {"k": k, "kf": filterpy_kalman(), "z": 0.61}
    t_ndr = per_call("k.predict(); k.update(z)", names, 1_000_000 // scale)
    t_ndr_step = per_call("k.step(z)", names, 1_000_000 // scale)
    kf = names["kf"]
    if kf is not None:
        t_fp = per_call("kf.predict(); kf.update(z)", names, 20_000 // scale)
        rows.append(("Kalman3 predict()+update(z)", us(t_ndr), us(t_fp), f"{t_fp / t_ndr:.0f}×"))
    else:
        rows.append(("Kalman3 predict()+update(z)", us(t_ndr), "(filterpy absent)", ""))
    rows.append(("Kalman3 step(z)", us(t_ndr_step), "", ""))

    # --- Kalman3, batch over n_batch samples.
    t_batch = once(lambda: ndr.kalman3_filter(z_series, period=T, sigma_q=SIGMA_Q), 5)
    label = f"Kalman3 batch over {samples} samples"
    kf = filterpy_kalman()
    if kf is not None:

        def filterpy_loop():
            f = filterpy_kalman()
            for z in z_series:
                f.predict()
                f.update(z)

        t_fp_batch = once(filterpy_loop, 1)
        rows.append((label, ms(t_batch), ms(t_fp_batch), f"{t_fp_batch / t_batch:.0f}×"))
    else:
        rows.append((label, ms(t_batch), "(filterpy absent)", ""))
    rows.append(("  per sample", us(t_batch / n_batch), "", ""))

    # --- RLS, 5 weights (the Arx2 regressor size).
    n = 5
    X = rng.normal(size=(n_batch, n))
    d = X @ np.array([0.05, 0.1, 0.05, -1.4, 0.5]) + rng.normal(scale=0.01, size=n_batch)
    # One adapt per sample from a Python loop (the loop's own cost included
    # on both sides): repeating one sample would wind the covariance up.
    rows_x, rows_d = list(X), [float(v) for v in d]

    def adapt_loop(f, count):
        for x, dk in zip(rows_x[:count], rows_d[:count]):
            f.adapt(dk, x)

    n_calls = 20_000 // scale
    t_rls = per_sample(lambda: adapt_loop(ndr.Rls(n, lam=0.99, delta=1e3), n_calls), n_calls)
    pa = padasip_rls(n)
    if pa is not None:
        t_pa = per_sample(lambda: adapt_loop(padasip_rls(n), n_calls), n_calls, 1)
        rows.append(("Rls(5) adapt(d, x) in a Python loop", us(t_rls), us(t_pa), f"{t_pa / t_rls:.0f}×"))
    else:
        rows.append(("Rls(5) adapt(d, x) in a Python loop", us(t_rls), "(padasip absent)", ""))
    t_rls_batch = once(lambda: ndr.rls_filter(d, X, lam=0.99, delta=1e3), 5)
    label = f"Rls(5) batch over {samples} samples"
    if pa is not None:
        t_pa_batch = once(lambda: padasip_rls(n).run(d, X), 1)
        rows.append((label, ms(t_rls_batch), ms(t_pa_batch), f"{t_pa_batch / t_rls_batch:.0f}×"))
    else:
        rows.append((label, ms(t_rls_batch), "(padasip absent)", ""))

    versions = [f"ndr {ndr.__version__}", f"numpy {np.__version__}"]
    for name in ("filterpy", "padasip"):
        try:
            versions.append(f"{name} {metadata.version(name)}")
        except metadata.PackageNotFoundError:
            versions.append(f"{name} absent")
    print(f"machine: {cpu_model()}, {os.cpu_count()} CPUs, {platform.system()} {platform.release()}")
    print(f"python:  {platform.python_implementation()} {platform.python_version()}; " + ", ".join(versions))
    print(f"command: {' '.join([os.path.basename(sys.executable), *sys.argv])}")
    print()
    print("| measure | ndr | filterpy / padasip | ratio |")
    print("|---|---|---|---|")
    for row in rows:
        print("| " + " | ".join(row) + " |")


if __name__ == "__main__":
    main()
