#!/usr/bin/env python
"""Regenerate the hard-disk fluid structure-factor table
``src/corona/data/hard_disk_structure_factor.npz``.

Every row ``η`` of the table is an event-chain Monte Carlo run of
``corona.reference.hard_disk.simulate_hard_disks`` (N = 2000 disks in a periodic square
box, two independent chains, settings from :func:`row_settings`), seeded with
``seed + round(1000 η)`` so that any single row can be regenerated bit for bit
on its own.  The raw box-wave-vector data of each row are kept in the table
file, and :func:`corona.reference.hard_disk.smooth_structure_factor_row` turns them into
the smooth row on the fixed ``qσ`` grid (documented there).

Usage
-----
    python scripts/make_hard_disk_table.py                # all rows (long)
    python scripts/make_hard_disk_table.py --jobs 2       # chains in parallel
    python scripts/make_hard_disk_table.py --workers 2    # rows in parallel (local Dask cluster)
    python scripts/make_hard_disk_table.py --scheduler tcp://host:8786   # rows on a Dask cluster
    python scripts/make_hard_disk_table.py --eta 0.72     # one row, others kept
    python scripts/make_hard_disk_table.py --eta 0.5 --top-up   # add the chains a stored row lacks
    python scripts/make_hard_disk_table.py --assemble-only   # re-smooth stored raw data

Rows not simulated in this call are taken from ``--work-dir`` (raw files of
earlier calls) or else from the existing table file.
"""
from __future__ import annotations

import argparse
import datetime
import json
import os
import platform
import sys
import time

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, os.path.join(ROOT, "src"))

from corona.reference import hard_disk as hd  # noqa: E402

DEFAULT_OUT = os.path.join(ROOT, "src", "corona", "data", "hard_disk_structure_factor.npz")
DEFAULT_WORK = os.path.join(ROOT, "build", "hard_disk_rows")

#: Rows: 0.05 steps up to 0.5 (S varies slowly and smoothly with η there),
#: 0.02 steps to 0.6, 0.01 steps to 0.72 (fast growth of the peak, freezing).
ETA_GRID = np.round(np.concatenate([np.arange(0.0, 0.5001, 0.05),
                                    np.arange(0.52, 0.6001, 0.02),
                                    np.arange(0.61, 0.7201, 0.01)]), 4)

N_DISKS = 2000
N_CHAINS = 2
SEED = 20250
Q_SIGMA_MAX = 42.0       # measured range; the table stops at 40 (spline margin)
BIN_WIDTH = 0.05


def row_settings(eta: float) -> dict:
    """Monte Carlo settings of one row (sweeps per chain)."""
    if eta <= 0.3 + 1e-9:     # fast decorrelation, costly sweeps (long free paths)
        n_eq, n_sw, every = 2000, 12000, 100
    elif eta <= 0.5 + 1e-9:
        n_eq, n_sw, every = 3000, 20000, 150
    elif eta < 0.685:
        n_eq, n_sw, every = 8000, 50000, 200
    else:       # coexistence / hexatic region: slow orientational relaxation, so
        # long runs; snapshots (all wave vectors below qσ = 15) less often
        n_eq, n_sw, every = 15000, 55000, 400
    return dict(n_disks=N_DISKS, n_sweeps=n_sw, n_equilibration=n_eq, sample_every=every,
                n_chains=chains_for(eta), q_sigma_max=Q_SIGMA_MAX, bin_width=BIN_WIDTH,
                seed=SEED + int(round(1000 * eta)))


#: Rows run with more independent chains (issue 18: the smoothed rows' own
#: error bars below 0.003 at the rows it names, 0.3, 0.5 and 0.65), {η: chains}.
#: The first chains of a row are those of the shorter runs
#: (``SeedSequence.spawn``), so extra chains only add statistics, and
#: ``--top-up`` adds them to stored rows.  The smoothed row's error falls more
#: slowly than 1/√chains (the smoother sharpens as the data improve), hence 12,
#: 45 and 26 chains there; the rows 0.05–0.45 got 4–8 chains (error bars
#: ~0.004–0.005 at the first peak), the rest keep ``N_CHAINS``: every row at
#: < 0.003 would take ≈ 3–4 CPU hours.
EXTRA_CHAINS = {0.05: 4, 0.1: 4, 0.15: 4, 0.2: 4, 0.25: 4, 0.3: 12,
                0.35: 8, 0.4: 8, 0.45: 8, 0.5: 45, 0.65: 26}


def chains_for(eta: float) -> int:
    """Independent chains of the row ``eta``."""
    for e, n in EXTRA_CHAINS.items():
        if abs(eta - e) < 1e-6:
            return n
    return N_CHAINS


def row_file(work_dir: str, eta: float, first_chain: int = 0) -> str:
    tail = "" if first_chain == 0 else f"_from{first_chain}"
    return os.path.join(work_dir, f"eta_{eta:.4f}{tail}.npz")


def simulate_row(eta: float, jobs: int, work_dir: str, progress: bool = True, first_chain: int = 0,
                 n_chains: int | None = None) -> dict:
    """Run one row (or its chains ``first_chain …``) here and store its raw data in ``work_dir``."""
    st = row_settings(eta)
    if n_chains is not None:
        st["n_chains"] = int(n_chains)
    if first_chain:
        st["first_chain"] = int(first_chain)
    raw = hd.table_row(eta, st, jobs=jobs, progress=progress)
    save_row(work_dir, raw, first_chain)
    return raw


def _chains(r: dict) -> int:
    return int(json.loads(str(r["settings"])).get("n_chains", N_CHAINS))


def _merge(parts: list[dict]) -> dict:
    """One row from runs of disjoint chains of the same seed sequence: means
    weighted by chains (every chain has the same snapshots), independent
    standard errors combined."""
    if len(parts) == 1:
        return parts[0]
    n = np.array([_chains(p) for p in parts], float)
    w = n / n.sum()
    out = dict(parts[0])

    def mean(key):
        return sum(wk * np.asarray(p[key], float) for wk, p in zip(w, parts))

    def err(key):
        return np.sqrt(sum((wk * np.asarray(p[key], float)) ** 2 for wk, p in zip(w, parts)))

    for key in ("S", "g", "Z", "contact", "psi6"):
        out[key] = mean(key)
    for key in ("S_err", "g_err", "Z_err", "contact_err"):
        out[key] = err(key)
    out["min_distance"] = min(float(p["min_distance"]) for p in parts)
    for key in ("cpu", "wall", "events", "n_snapshots"):
        out[key] = sum(p[key] for p in parts)
    st = json.loads(str(parts[0]["settings"]))
    st["n_chains"] = int(n.sum())
    st.pop("first_chain", None)
    st["parts"] = [json.loads(str(p["settings"])) for p in parts]
    out["settings"] = json.dumps(st)
    return out


def have_chains(work_dir: str, eta: float) -> int:
    """Chains of the row stored in ``work_dir`` (0 when none)."""
    parts = _row_parts(work_dir, eta)
    return sum(_chains(p) for p in parts)


def _row_parts(work_dir: str, eta: float) -> list[dict]:
    import glob
    files = sorted(glob.glob(os.path.join(work_dir, f"eta_{eta:.4f}*.npz")))
    parts = []
    for f in files:

        with np.load(f) as z:
            parts.append({k: z[k] for k in z.files})
    return parts


def save_row(work_dir: str, raw: dict, first_chain: int = 0) -> None:
    os.makedirs(work_dir, exist_ok=True)
    np.savez(row_file(work_dir, float(raw["eta"]), first_chain), **raw)
    print(f"η={float(raw['eta']):.4f}: Z={float(raw['Z']):.4f}±{float(raw['Z_err']):.4f} "
          f"g(σ+)={float(raw['contact']):.4f}±{float(raw['contact_err']):.4f} ψ6={float(raw['psi6']):.3f} "
          f"min d={float(raw['min_distance']):.6f} cpu={float(raw['cpu']):.1f}s "
          f"wall={float(raw['wall']):.1f}s", flush=True)


def simulate_rows(etas, work_dir: str, executor=None, jobs: int = 1, progress: bool = True,
                  settings=row_settings) -> list:
    """Every row of ``etas``, one task per row of ``executor`` (a
    :class:`corona._executor.Executor`; default: here, one after the other).
    Each row is stored in ``work_dir`` as it arrives; a failed row is
    reported and the others finish.  Returns the raw rows (None where failed).
    """
    from corona.apps.sweep import Executor
    executor = executor or Executor(workers=0)
    here = executor.in_process
    tasks = [(float(e), settings(float(e)), jobs if here else 1, progress and here) for e in etas]

    def store(o):
        if o.ok:
            save_row(work_dir, o.value)

    outs = executor.map(hd.table_row, tasks, [f"η={e:.4f}" for e in etas], desc="hard-disk rows",
                        progress=progress and not here, on_result=store)
    return [o.value if o.ok else None for o in outs]


def load_row(work_dir: str, eta: float, old: dict | None):
    parts = _row_parts(work_dir, eta)
    if parts:
        return _merge(parts)
    if old is not None:
        i = np.flatnonzero(np.isclose(old["eta"], eta))
        if i.size:
            i = int(i[0])
            return dict(eta=eta, q=old["raw_q"][i].astype(float), S=old["raw_S"][i].astype(float),
                        S_err=old["raw_S_err"][i].astype(float),
                        n_vectors=old["raw_n_vectors"][i], Z=old["Z"][i], Z_err=old["Z_err"][i],
                        contact=old["contact_value"][i], contact_err=old["contact_value_err"][i],
                        psi6=old["psi6"][i], min_distance=old["min_distance"][i],
                        cpu=old["cpu_seconds"][i], wall=old["wall_seconds"][i],
                        events=old["events"][i], g=old["g"][i].astype(float),
                        g_err=old["g_err"][i].astype(float), r=old["r_sigma"],
                        box_length=old["box_length"][i], n_snapshots=old["n_snapshots"][i],
                        settings=str(old["settings"][i]))
    return None


def smooth_row(r: dict) -> dict:
    """The table row (``S`` on the fixed grid, ``tail``, ``S0``) from raw data."""
    ok = np.isfinite(r["S"])
    return hd.smooth_structure_factor_row(r["q"][ok], r["S"][ok], r["S_err"][ok],
                                          float(r["eta"]), Z=float(r["Z"]))


def row_error(r: dict, n_resamples: int) -> np.ndarray:
    """Standard error of the smoothed row (parametric bootstrap of the smoothing)."""
    ok = np.isfinite(r["S"])
    return hd.smoothed_row_error(r["q"][ok], r["S"][ok], r["S_err"][ok], float(r["eta"]), Z=float(r["Z"]),
                                 n_resamples=n_resamples, seed=int(round(1000 * float(r["eta"]))))


def assemble(work_dir: str, out: str, old: dict | None, n_resamples: int = 12) -> None:
    q_grid = hd.TABLE_Q_SIGMA
    rows, missing = [], []
    for eta in ETA_GRID:
        if eta == 0.0:
            rows.append(None)
            continue
        r = load_row(work_dir, float(eta), old)
        if r is None:
            missing.append(float(eta))
        rows.append(r)
    if missing:
        raise SystemExit(f"no data for rows η = {missing}; simulate them (--eta ...)")
    n_eta, n_q = len(ETA_GRID), q_grid.size
    n_bins = int(round(Q_SIGMA_MAX / BIN_WIDTH))
    S = np.ones((n_eta, n_q))
    S_err = np.zeros((n_eta, n_q))
    tail = np.zeros((n_eta, 3))
    S0 = np.ones(n_eta)
    out_d = {k: np.zeros(n_eta) for k in ("Z", "Z_err", "contact_value", "contact_value_err",
                                          "psi6", "min_distance", "cpu_seconds", "wall_seconds",
                                          "box_length")}
    out_d["events"] = np.zeros(n_eta, np.int64)
    out_d["n_snapshots"] = np.zeros(n_eta, np.int64)
    raw_q = np.full((n_eta, n_bins), np.nan)
    raw_S = np.full((n_eta, n_bins), np.nan)
    raw_S_err = np.full((n_eta, n_bins), np.nan)
    raw_nv = np.zeros((n_eta, n_bins), np.int32)
    r_sigma = None
    g = None
    settings = []
    for i, (eta, r) in enumerate(zip(ETA_GRID, rows)):
        if r is None:
            out_d["Z"][i] = 1.0
            out_d["contact_value"][i] = 1.0
            out_d["min_distance"][i] = np.nan
            settings.append("{}")
            continue
        row = smooth_row(r)
        S[i] = row["S"]
        S_err[i] = row_error(r, n_resamples)
        print(f"η={eta:.4f}: smoothed row's error max {S_err[i].max():.4f} (at qσ = "
              f"{q_grid[np.argmax(S_err[i])]:.2f}), median {np.median(S_err[i]):.4f}", flush=True)
        tail[i] = row["tail"]
        S0[i] = row["S0"]
        out_d["Z"][i], out_d["Z_err"][i] = r["Z"], r["Z_err"]
        # contact value re-derived from the stored g(r) with the current fit
        out_d["contact_value"][i] = hd._contact_fit(np.asarray(r["r"], float),
                                                    np.asarray(r["g"], float), float(r["Z"]))
        out_d["contact_value_err"][i] = r["contact_err"]
        for k_out, k_in in (("psi6", "psi6"), ("min_distance", "min_distance"),
                            ("cpu_seconds", "cpu"), ("wall_seconds", "wall"), ("events", "events"),
                            ("box_length", "box_length"), ("n_snapshots", "n_snapshots")):
            out_d[k_out][i] = r[k_in]
        raw_q[i], raw_S[i], raw_S_err[i], raw_nv[i] = r["q"], r["S"], r["S_err"], r["n_vectors"]
        if g is None:
            r_sigma = np.asarray(r["r"], float)
            g = np.ones((n_eta, r_sigma.size))
            g_err = np.zeros((n_eta, r_sigma.size), np.float32)
        g[i], g_err[i] = r["g"], r["g_err"]
        settings.append(str(r["settings"]))
    meta = dict(format_version=hd.TABLE_FORMAT_VERSION, n_disks=N_DISKS, n_chains=N_CHAINS,  # per row: "chains"
                seed=SEED, date=datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
                generator="scripts/make_hard_disk_table.py", method=hd.TABLE_METHOD,
                S_err=f"standard error of each smoothed row (parametric bootstrap of the smoothing, "
                      f"{n_resamples} resamples of the binned data within their blocking errors)",
                chains={f"{e:g}": chains_for(float(e)) for e in ETA_GRID if e > 0},
                python=platform.python_version(), numpy=np.__version__,
                total_cpu_seconds=float(out_d["cpu_seconds"].sum()))
    os.makedirs(os.path.dirname(out), exist_ok=True)
    tmp = out + ".tmp.npz"
    np.savez_compressed(tmp, eta=ETA_GRID, q_sigma=q_grid, S=S, S_err=S_err.astype(np.float16), S0=S0, tail=tail,
                        raw_q=raw_q, raw_S=raw_S, raw_S_err=raw_S_err, raw_n_vectors=raw_nv,
                        r_sigma=r_sigma, g=g, g_err=g_err, settings=np.array(settings),
                        metadata=json.dumps(meta), **out_d)
    os.replace(tmp, out)
    print(f"wrote {out} ({os.path.getsize(out) / 1e6:.2f} MB); total CPU "
          f"{meta['total_cpu_seconds'] / 60:.1f} min")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--eta", type=float, action="append",
                    help="regenerate only this row (repeatable); must be on the grid")
    ap.add_argument("--jobs", type=int, default=1,
                    help="processes per row (its chains in parallel; rows in this process only)")
    ap.add_argument("--workers", type=int, default=0,
                    help="0: rows one after the other here; N: a local Dask cluster of N workers, "
                         "one row per task")
    ap.add_argument("--scheduler", default=None,
                    help="an existing Dask scheduler (tcp://host:8786), one row per task")
    ap.add_argument("--timeout", type=float, default=10.0, help="seconds to wait for --scheduler")
    ap.add_argument("--out", default=DEFAULT_OUT)
    ap.add_argument("--work-dir", default=DEFAULT_WORK)
    ap.add_argument("--assemble-only", action="store_true", help="re-smooth stored raw rows")
    ap.add_argument("--no-assemble", action="store_true", help="simulate only")
    ap.add_argument("--base", default=None,
                    help="table that provides the rows not simulated now (default: --out if it "
                         "exists, else the shipped table)")
    ap.add_argument("--quiet", action="store_true")
    ap.add_argument("--top-up", action="store_true",
                    help="run only the chains a row in --work-dir still lacks (of chains_for(η))")
    ap.add_argument("--error-resamples", type=int, default=12,
                    help="bootstrap resamples of each row's smoothing for its error bars")
    a = ap.parse_args(argv)
    old = None
    base = a.base or (a.out if os.path.exists(a.out) else DEFAULT_OUT)
    if os.path.exists(base):
        with np.load(base) as z:
            old = {k: z[k] for k in z.files}
    if not a.assemble_only:
        if a.eta:
            etas = []
            for e in a.eta:
                i = np.flatnonzero(np.isclose(ETA_GRID, e, atol=1e-6))
                if i.size == 0:
                    raise SystemExit(f"--eta {e} is not a table row; rows: {ETA_GRID.tolist()}")
                etas.append(float(ETA_GRID[i[0]]))
        else:
            etas = [float(e) for e in ETA_GRID if e > 0]
        from corona._validation import CoronaError
        from corona.apps.sweep import Executor
        t0 = time.perf_counter()
        if a.top_up:     # only the chains each row still lacks (same seed sequence), here
            rows = []
            for eta in (e for e in etas if e > 0):
                have = have_chains(a.work_dir, eta)
                need = chains_for(eta) - have
                if not have:
                    rows.append(simulate_row(eta, a.jobs, a.work_dir, progress=not a.quiet))
                elif need > 0:
                    rows.append(simulate_row(eta, a.jobs, a.work_dir, progress=not a.quiet,
                                             first_chain=have, n_chains=need))
        else:
            try:
                with Executor(None if a.scheduler else a.workers, a.scheduler, timeout=a.timeout,
                              log=print) as ex:
                    rows = simulate_rows([e for e in etas if e > 0], a.work_dir, ex, jobs=a.jobs,
                                         progress=not a.quiet)
            except CoronaError as err:
                raise SystemExit(f"make_hard_disk_table: error: {err}") from None
        print(f"simulated {len(etas)} row(s) in {time.perf_counter() - t0:.1f} s wall", flush=True)
        if any(r is None for r in rows):
            raise SystemExit("make_hard_disk_table: some rows failed (see above); nothing assembled")
    if not a.no_assemble:
        assemble(a.work_dir, a.out, old, a.error_resamples)


if __name__ == "__main__":
    main()
