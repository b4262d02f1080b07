"""Feature oracle: the best clearance estimate the per-event features allow (docs/ACCURACY.md).

What it is: a bound on what any estimator built on the shipped per-event features (ln RMS and
ln peak of the 3-25 Hz band-passed steering angle over the braking window, ln RMS over the
cruise window; src/observer/features.rs, `z` and `z_cruise`) can reach on a fleet vehicle,
obtained by giving it everything the product does not know: the vehicle's parameters,
unbalance, road-noise level and wheel phases. For each vehicle and each clearance of a grid,
the same vehicle is driven again R times (`firmware-sim fleet --seed-base SEED --vehicles 1
--clearance-mm C --replicate r`, r = 1..R: the seed's vehicle and braking plan, the noise drawn
anew), and each event's features are read back with `shimmy estimate` (no table). Per grid
clearance the event's likelihood is Gaussian: the mean of its R replicates, and a covariance
pooled over the vehicle's events (times 1 + 1/R for the estimated mean). Between grid points
mean and covariance are interpolated linearly in ln c. The prior is the fleet's own
(log-uniform 0.03-0.4 mm), the events are independent given the vehicle, and the point
estimate is the posterior median: the estimate with the least expected absolute error under
this likelihood. Its 90 % interval coverage checks the Gaussian model (it should be near 90 %).

What it is not: a bound on what the raw steering signal holds (a new feature can beat it), nor
a product estimator (it needs the vehicle's true nuisances).

Usage (from the repository root):
  docs/experiments/feature_oracle_runs.sh ORC DIR [DIR ...]      # the model runs (see there)
  ORACLE_TABLE=config/vehicles/shimmy_reference/table.json \
      python3 docs/experiments/feature_oracle.py ORC ORC/plan.json [FLEET.json DIR ...]
FLEET.json / DIR pairs are the product's `firmware-sim fleet --json` results on the same logs,
printed beside the oracle. Environment: ORACLE_TABLE adds the rows of the shipped law (the
table's linear model, src/observer/linear.rs); ORACLE_MC=1 the law with the nuisances unknown
(Monte Carlo; ORACLE_MC_DRAWS, ORACLE_MC_SEED; ORACLE_MC=2 also with normal priors);
ORACLE_KNOWN="5;1,5,7" the law with those variables known (0-6: x0-x6, 7: u);
ORACLE_NO_BETWEEN=1 leaves the law's per-vehicle misfit out of the Monte Carlo;
ORACLE_FLAGS=--rows prints every vehicle.
"""
import json
import math
import os
import sys

import numpy as np

Z_FLOOR_DEG = (0.02, 0.05)  # src/observer/features.rs
PRIOR_MM = (0.03, 0.4)  # the fleet's clearance law (firmware-sim/src/fleet.rs)
N_FINE = 400


def zvec(e):
    """The event's z (rms, peak, cruise; cruise NaN when absent)."""
    f0, f1 = Z_FLOOR_DEG
    z = [0.5 * math.log(e["rms_sw_bp_deg"] ** 2 + f0 * f0),
         0.5 * math.log(e["peak_sw_bp_deg"] ** 2 + f1 * f1)]
    cr = e.get("cruise_rms_sw_bp_deg")
    z.append(0.5 * math.log(cr * cr + f0 * f0) if cr is not None else float("nan"))
    return z


def used_events(path):
    d = json.load(open(path))
    return [(e["t_start"], zvec(e), e["v0_kmh"], e["decel_g"])
            for e in d["events"] if e["used"] and e["rms_sw_bp_deg"]]


def match(obs, rep, tol=1.0):
    """Replicate z for each observed event (nearest start within tol s), NaN if none."""
    out = []
    for t, *_ in obs:
        best = min(rep, key=lambda r: abs(r[0] - t), default=None)
        out.append(best[1] if best and abs(best[0] - t) < tol else [float("nan")] * 3)
    return np.array(out)


def loglik(zo, mu, cov, dims):
    """Gaussian log density of zo[dims] under (mu, cov)[dims]."""
    d = np.array(dims)
    x = zo[d] - mu[d]
    c = cov[np.ix_(d, d)]
    sign, logdet = np.linalg.slogdet(c)
    return -0.5 * (x @ np.linalg.solve(c, x) + logdet + len(d) * math.log(2 * math.pi))


def replicate_stats(orc, seed, grid, n_rep):
    """Observed z (event x 3), replicate means (grid x event x 3), pooled covariances."""
    obs = used_events(os.path.join(orc, "obs", f"ev_{seed}.json"))
    zo = np.array([o[1] for o in obs])
    n_ev = len(obs)
    mus, covs = [], []
    for i in range(len(grid)):
        reps = [match(obs, used_events(os.path.join(orc, f"c{i}_r{r}", f"ev_{seed}.json")))
                for r in range(1, n_rep + 1)]
        z = np.stack(reps)  # rep x event x 3
        mu = np.nanmean(z, axis=0)
        res = (z - mu)[~np.isnan(z).any(axis=2)]
        dof = max(len(res) - n_ev, 3)
        cov = res.T @ res / dof * (1 + 1 / max(n_rep, 1))
        cov += np.eye(3) * 1e-6
        mus.append(mu)
        covs.append(cov)
    return obs, zo, np.array(mus), covs


def posterior(zo, mus, covs, grid, dims_all):
    """Posterior median and 90 % interval over the fleet prior (fine grid in ln c)."""
    n_ev = len(zo)
    lg = np.log(grid)
    fine = np.linspace(math.log(PRIOR_MM[0]), math.log(PRIOR_MM[1]), N_FINE)
    ll = np.zeros(N_FINE)
    for k, x in enumerate(fine):
        j = min(max(np.searchsorted(lg, x) - 1, 0), len(grid) - 2)
        w = (x - lg[j]) / (lg[j + 1] - lg[j])
        cov = (1 - w) * covs[j] + w * covs[j + 1]
        for e in range(n_ev):
            mu = (1 - w) * mus[j][e] + w * mus[j + 1][e]
            dims = [d for d in dims_all if not (math.isnan(zo[e][d]) or math.isnan(mu[d]))]
            if dims:
                ll[k] += loglik(zo[e], mu, cov, dims)
    p = np.exp(ll - ll.max())
    cdf = np.cumsum(p) / p.sum()
    q = lambda a: math.exp(np.interp(a, cdf, fine))
    return q(0.5), (q(0.05), q(0.95)), n_ev


NOMINAL = {"kingpin_stiffness_nm_per_rad": 500.0, "kingpin_damping_nms_per_rad": 30.0,
           "tie_rod_stiffness_n_per_m": 4.0e6, "restraint_stiffness_n_per_m": 1.0e5,
           "restraint_damping_ns_per_m": 6000.0}  # config/vehicle/default.toml (MODEL.md 9)
UNBALANCE_KGM, NOISE_NM = 2e-3, 0.2


def toml_values(path):
    out = {}
    for line in open(path):
        if "=" in line and not line.lstrip().startswith(("#", "[")):
            k, v = line.split("=", 1)
            try:
                out[k.strip()] = float(v.split("#")[0])
            except ValueError:
                pass
    return out


def law_vars(folder, seed):
    """The shipped law's variables x0-x6, u of a fleet vehicle (src/observer/emulate.rs coords)."""
    v = toml_values(os.path.join(folder, f"vehicle_{seed}.toml"))
    sc = toml_values(os.path.join(folder, f"fleet_{seed}.toml"))
    x = [(v[k] / n - 1.0) / 0.1 for k, n in NOMINAL.items()]
    lo, hi = 0.5, 2.0
    x.append((math.log(sc["unbalance_kgm"] / UNBALANCE_KGM) - 0.5 * math.log(hi * lo))
             / (0.5 * math.log(hi / lo)))
    lo, hi = 0.7, 1.4
    x.append((2 * sc["road_noise_nm"] / NOISE_NM - lo - hi) / (hi - lo))
    truth = json.load(open(os.path.join(folder, f"fleet_{seed}.truth.json")))
    x.append(truth["events"][0]["unbalance_phase_cos"])
    return x


def term_value(term, x, d):
    if term == "1":
        return 1.0
    val = 1.0
    for f in term.split("*"):
        name, _, pw = f.partition("^")
        pw = int(pw or 1)
        xv = (d - 0.55) / 0.25 if name == "d" else (x[7] if name == "u" else x[int(name[1:])])
        # (x may hold numbers or numpy columns)
        val *= xv ** pw
    return val


def bracket(axis, x):
    if x <= axis[0]:
        return 0, 0.0
    if x >= axis[-1]:
        return len(axis) - 2, 1.0
    i = max(k for k in range(len(axis)) if axis[k] <= x)
    return i, (x - axis[i]) / (axis[i + 1] - axis[i])


def clearance_pos(table, ln_c):
    """(index, weight) of ln c on the table's clearance axis."""
    return bracket([math.log(c) for c in table["clearance_mm"]], ln_c)


def law_coef(table, pos, v0):
    """The law's coefficients (3 features x terms) at clearance position `pos` and speed v0,
    interpolated bilinearly as src/observer/linear.rs `coef_interp` does."""
    lin = table["linear"]
    coef = lin["coef"]
    nk, nv = len(lin["terms"]), len(table["speed_kmh"])
    (ic, wc), (iv, wv) = pos, bracket(table["speed_kmh"], v0)
    b = np.zeros((3, nk))
    for dc, fc in ((0, 1 - wc), (1, wc)):
        for dv, fv in ((0, 1 - wv), (1, wv)):
            i = ((ic + dc) * nv + iv + dv) * 3 * nk
            b += fc * fv * coef[i:i + 3 * nk].reshape(3, nk)
    return b


def table_cov(table, key, pos):
    """The table's `within` or `between` covariance at clearance position `pos`."""
    ic, wc = pos
    m = table["linear"][key]
    return (1 - wc) * np.array(m[ic]) + wc * np.array(m[ic + 1])


def table_covs(table, grid):
    """The table's within-vehicle event covariance at each grid clearance (ln c interpolated)."""
    return [table_cov(table, "within", clearance_pos(table, math.log(c))) for c in grid]


def law_means(table, x, events, grid):
    """The law's feature means (event x grid clearance x 3) at the vehicle's true variables."""
    terms = table["linear"]["terms"]
    out = np.zeros((len(events), len(grid), 3))
    for e, (v0, d) in enumerate(events):
        basis = np.array([term_value(t, x, d) for t in terms])
        for g, c in enumerate(grid):
            out[e, g] = law_coef(table, clearance_pos(table, math.log(c)), v0) @ basis
    return out


MC_DRAWS = int(os.environ.get("ORACLE_MC_DRAWS", "10000"))
MC_SEED = int(os.environ.get("ORACLE_MC_SEED", "1"))


def law_marginal(table, events, zo, n_draw=MC_DRAWS, seed=MC_SEED, gauss=(), known=None,
                 priors=(PRIOR_MM, (0.02, 0.6))):
    """The shipped law with the nuisances unknown: Monte Carlo over their uniform priors
    (x0-x6 on [-1, 1], the phase difference uniform, one misfit offset per drawn vehicle from
    the table's between-vehicle covariance), the table's within-vehicle covariance per event,
    the events multiplied (no tempering), on a clearance grid of ln-steps 0.07 over 0.02-0.6 mm
    with the law's coefficients interpolated in ln c (as the product's fine grid). Returns the
    posterior median and 90 % interval for each clearance prior of `priors` (log-uniform)."""
    rng = np.random.default_rng(seed)
    terms = table["linear"]["terms"]
    fine = np.linspace(math.log(0.02), math.log(0.6), 49)
    x = np.concatenate([rng.uniform(-1, 1, (n_draw, 7)),
                        np.cos(rng.uniform(0, math.pi, (n_draw, 1)))], axis=1)
    for k in gauss:  # these coordinates from the normal of the same variance instead
        x[:, k] = rng.normal(0, math.sqrt(1 / 3), n_draw)
    for k, v in (known or {}).items():  # these variables at the vehicle's true value
        x[:, k] = v
    w = rng.standard_normal((n_draw, 3))
    ll = np.zeros((len(fine), n_draw))
    cells = [clearance_pos(table, g) for g in fine]
    covs = []
    for pos in cells:
        within, between = table_cov(table, "within", pos), table_cov(table, "between", pos)
        if os.environ.get("ORACLE_NO_BETWEEN"):  # leave out the law's per-vehicle misfit
            between = np.zeros((3, 3))
        covs.append((within, np.linalg.cholesky(between + 1e-9 * np.eye(3))))
    cols = [x[:, k] for k in range(8)]
    for e, (v0, d) in enumerate(events):
        basis = np.stack([np.broadcast_to(term_value(t, cols, d), (n_draw,)) for t in terms], 1)
        dims = [k for k in range(3) if not math.isnan(zo[e][k])]
        for g, pos in enumerate(cells):
            within, lb = covs[g]
            mu = basis @ law_coef(table, pos, v0).T + w @ lb.T  # draws x 3
            r = zo[e][dims] - mu[:, dims]
            cw = within[np.ix_(dims, dims)]
            ci = np.linalg.inv(cw)
            ll[g] += -0.5 * np.einsum("ni,ij,nj->n", r, ci, r) - 0.5 * np.linalg.slogdet(cw)[1]
    m = ll.max()
    with np.errstate(divide="ignore"):
        ev = np.log(np.exp(ll - m).mean(axis=1)) + m  # ln p(z | c) on the grid
    out = []
    for lo, hi in priors:
        inside = (fine >= math.log(lo) - 1e-9) & (fine <= math.log(hi) + 1e-9)
        f, lp = fine[inside], ev[inside]
        p = np.exp(lp - lp.max())
        # mass uniform in ln c over each point's cell, as the product's quantiles
        edges = np.concatenate([[f[0]], (f[1:] + f[:-1]) / 2, [f[-1]]])
        cdf = np.concatenate([[0], np.cumsum(p)]) / p.sum()
        q = lambda a: math.exp(np.interp(a, cdf, edges))
        out.append((q(0.5), (q(0.05), q(0.95)), len(events)))
    return out


def main(args):
    orc, plan = args[0], json.load(open(args[1]))
    grid = plan["grid"]
    product = {}
    for res, folder in zip(args[2::2], args[3::2]):
        for v in json.load(open(res))["vehicles"]:
            product[(os.path.basename(folder.rstrip("/")), v["seed"])] = v
    n_rep = sum(os.path.isdir(os.path.join(orc, f"c0_r{r}")) for r in range(1, 50))
    variants = {"rms+peak+cruise": [0, 1, 2], "rms+peak": [0, 1], "rms": [0]}
    table = json.load(open(os.environ["ORACLE_TABLE"])) if os.environ.get("ORACLE_TABLE") else None
    if table:
        table["linear"]["coef"] = np.array(table["linear"]["coef"])  # once, for law_coef
    extra = []
    rows = []
    for folder, seed in plan["sel"]:
        if not os.path.exists(os.path.join(orc, f"c{len(grid) - 1}_r{n_rep}", f"ev_{seed}.json")):
            continue
        truth = json.load(open(os.path.join(folder, f"fleet_{seed}.eval.json")))
        c = truth["clearance_true_mm"]
        row = {"seed": seed, "c": c, "c_s": toml_values(os.path.join(
            folder, f"vehicle_{seed}.toml"))["kingpin_damping_nms_per_rad"]}
        obs, zo, mus, covs = replicate_stats(orc, seed, grid, n_rep)
        for name, dims in variants.items():
            row[name] = posterior(zo, mus, covs, grid, dims)
        if table:
            # the shipped law at the vehicle's true nuisances and phase, in place of the
            # replicates' means (the replicates' scatter kept)
            truth_x = law_vars(folder, seed)
            ev = [(o[2], o[3]) for o in obs]  # (v0 km/h, decel g) of each event
            law = law_means(table, truth_x, ev, grid)
            law = np.transpose(law, (1, 0, 2))
            row["law at truth"] = posterior(zo, law, covs, grid, [0, 1, 2])
            # the same two with the table's event scatter (within-vehicle covariance, pooled
            # over its vehicles) in place of this vehicle's own
            tcov = table_covs(table, grid)
            row["law at truth, table scatter"] = posterior(zo, law, tcov, grid, [0, 1, 2])
            row["oracle means, table scatter"] = posterior(zo, mus, tcov, grid, [0, 1, 2])
            row["law at truth, vehicle scatter diagonal"] = posterior(
                zo, law, [np.diag(np.diag(c)) for c in covs], grid, [0, 1, 2])
            for spec in filter(None, os.environ.get("ORACLE_KNOWN", "").split(";")):
                # e.g. ORACLE_KNOWN="5;1;7;1,5,7": the law with these variables known
                # (0-6: x0-x6, 7: u), the others unknown
                ks = [int(k) for k in spec.split(",")]
                row[f"known {spec}"] = law_marginal(
                    table, ev, zo, known={k: truth_x[k] for k in ks})[0]
                if f"known {spec}" not in extra:
                    extra.append(f"known {spec}")
            if os.environ.get("ORACLE_MC"):
                (row["law, nuisances unknown"],
                 row["same, prior 0.02-0.6"]) = law_marginal(table, ev, zo)
                if os.environ.get("ORACLE_MC") == "2":
                    (row["same, normal priors"],
                     row["same, prior 0.02-0.6, normal priors"]) = law_marginal(
                         table, ev, zo, gauss=(0, 2, 3, 4, 5, 6))
            g = int(np.argmin(np.abs(np.log(grid) - math.log(c))))
            row["law bias"] = np.nanmean(law[g] - mus[g], axis=0)
        pv = product.get((os.path.basename(folder.rstrip("/")), seed))
        if pv and pv["median_mm"] is not None:
            row["product"] = (pv["median_mm"], tuple(pv["interval_mm"]), pv["events_used"])
        rows.append(row)
    print(f"{len(rows)} vehicles with c >= 0.1 mm, {n_rep} replicates per grid clearance, "
          f"grid {len(grid)} points {grid[0]:.3f}-{grid[-1]:.3f} mm")
    rows.sort(key=lambda r: r["c_s"])
    n = len(rows)
    parts = [("all", rows)] + [
        (f"c_s {rows[k * n // 3]['c_s']:.1f}-{rows[(k + 1) * n // 3 - 1]['c_s']:.1f}",
         rows[k * n // 3:(k + 1) * n // 3]) for k in range(3)]
    for name in list(variants) + ["law at truth", "law at truth, table scatter", "oracle means, table scatter", "law at truth, vehicle scatter diagonal", "law, nuisances unknown", "same, prior 0.02-0.6", "same, normal priors", "same, prior 0.02-0.6, normal priors"] + extra + ["product"]:
        cells = []
        for label, part in parts:
            part = [r for r in part if name in r]
            if not part:
                continue
            err = [r[name][0] - r["c"] for r in part]
            cov = sum(r[name][1][0] <= r["c"] <= r[name][1][1] for r in part)
            cells.append(f"{label}: MAE {np.mean(np.abs(err)):.4f} bias {np.mean(err):+.4f} "
                         f"cov {cov}/{len(part)}")
        print(f"{name:16s} " + " | ".join(cells))
    if "--rows" in os.environ.get("ORACLE_FLAGS", ""):
        for r in rows:
            print(r["seed"], f"c {r['c']:.3f} c_s {r['c_s']:.1f}",
                  " ".join(f"{k} {r[k][0]:.3f}" for k in list(variants) + ["law at truth", "law at truth, table scatter", "oracle means, table scatter", "law at truth, vehicle scatter diagonal", "law, nuisances unknown", "same, prior 0.02-0.6", "same, normal priors", "same, prior 0.02-0.6, normal priors"] + extra + ["product"]
                           if k in r),
                  "law bias " + " ".join(f"{b:+.3f}" for b in r.get("law bias", [])))
    if table:
        for label, part in parts:
            if not part:
                continue
            b = np.array([r["law bias"] for r in part])
            print(f"law - replicate mean at the grid clearance nearest the truth, {label}: mean "
                  + " ".join(f"{x:+.3f}" for x in b.mean(0)) + ", vehicle std "
                  + " ".join(f"{x:.3f}" for x in b.std(0)) + " (ln RMS, ln peak, cruise)")


if __name__ == "__main__":
    main(sys.argv[1:])
