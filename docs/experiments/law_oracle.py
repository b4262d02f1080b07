"""What a response table's nuisance law says a vehicle's events tell, if the vehicle were known.

A measurement for docs/ACCURACY.md ("The MAE on the column plant: what knowing the vehicle
would give"), outside the product. For each vehicle of `firmware-sim fleet` runs (their
`--json FLEET.json` and `--work-dir FLEET`), it reads the events' torque features as
`shimmy estimate` reports them (ln RMS, ln peak and the pre-brake cruise RMS of the band-passed
torsion-bar torque, floored as src/observer/features.rs `z` does) and evaluates the table's law
(src/observer/linear.rs: the polynomial in the deceleration, the nuisance coordinates of
src/observer/emulate.rs `coords` and the wheels' phase cosine ψ, interpolated linearly in ln c
and in speed) at the vehicle's *true* coordinates, from its DIR/vehicle_SEED.toml, and each
event's true ψ, from DIR/fleet_SEED.truth.json. The events' likelihood over a clearance grid
is the estimator's Gaussian one: the event scatter `within` and the per-vehicle misfit
`between` of the table, the misfit integrated out in closed form. Two oracles:

* "vehicle known": every coordinate and each event's ψ known;
* "kingpin damping unknown": the same with c_s integrated over its prior (uniform, 9 points),
* "nothing known, prior integrated exactly": all ten coordinates (uniform on [-1, 1]) and the
  vehicle's ψ (the cosine of a uniform phase, one per vehicle as firmware-sim draws it)
  integrated by Monte Carlo over `--mc` draws (2,048 by default, the same draws for every
  vehicle and clearance): what a Bayesian estimator with this table and no approximation
  would conclude, against which the shipped estimator's closed-form and gridded
  marginalisation (src/observer/marginal.rs) and its alert lifecycle are measured,

each at likelihood power 1 and at the torque's shipped evidence power (0.2), with a
log-uniform prior on 0.02-0.6 mm, scored like `firmware-sim fleet` (alert at P(c > 0.1 mm) >=
0.7, posterior median, 90 % interval); the fleet's own estimates (the shipped estimator, which
knows none of it) are printed beside them. The oracles are as good as the law: what the law
misses for one vehicle (η) is integrated out, as in the estimator.

Usage (from the repository root, after `cargo build --release -p shimmy-monitor -p firmware-sim`
and the fleets of the Status table's dev rows):

    python3 docs/experiments/law_oracle.py --profile toyota_rav4 \\
        --table config/vehicles/toyota_rav4/table_torque.json dev97000 dev97500

Needs numpy. Writes DIR/est_SEED.json (the estimate of each log) and caches the likelihoods in
FLEET.oracle.npz; about 5 min per 40 vehicles on one core, most of it the logs' estimates and
the Monte Carlo oracle's 2,048 draws (`--mc 0` leaves that oracle out). Beside the estimator's alerts (the
alert standing at the end of the log, as `firmware-sim fleet` scores) it prints how many of its
final P(c > 0.1 mm) are >= 0.7, the quantity the oracles decide on.
"""
import argparse
import bisect
import json
import math
import os
import subprocess
import sys

import numpy as np

ROOT = os.path.normpath(os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", ".."))
# src/observer/features.rs Z_FLOOR_DEG: floors added in quadrature before the logs.
FLOOR = (0.02, 0.05)
# src/observer/simulate.rs NuisanceRanges::default(): the column's ranges (docs/COLUMN.md).
COLUMN = {"inertia_kgm2": (0.03, 0.05), "torsion_bar_nm_per_rad": (57.3, 171.9),
          "torsion_bar_damping_nms_per_rad": (0.01, 0.05)}
DAMPING_GRID = np.linspace(-1.0, 1.0, 9)
GRID = np.exp(np.linspace(math.log(0.02), math.log(0.6), 240))


def toml_numbers(path):
    """section.key -> number of a flat TOML file (the vehicle files firmware-sim writes)."""
    out, sec = {}, ""
    for line in open(path):
        line = line.split("#")[0].strip()
        if line.startswith("["):
            sec = line.strip("[]")
        elif "=" in line:
            k, v = (x.strip() for x in line.split("=", 1))
            try:
                out[f"{sec}.{k}"] = float(v)
            except ValueError:
                pass
    return out


def coords(p, nominal, prior):
    """The nuisance coordinates ξ ∈ [−1, 1]^10 of src/observer/emulate.rs `coords`."""
    rel = prior["stiffness_damping_rel"]
    f = lambda k: (p[f"steering.{k}"] / nominal[f"steering.{k}"] - 1.0) / rel
    ulo, uhi = prior["unbalance_factor"]
    nlo, nhi = prior["road_noise_factor"]
    u = p["excitation.unbalance_kgm"] / nominal["excitation.unbalance_kgm"]
    n = p["excitation.noise_std_nm"] / nominal["excitation.noise_std_nm"]
    lin = lambda x, lo, hi: (2 * x - lo - hi) / (hi - lo)
    return [f("kingpin_stiffness_nm_per_rad"), f("kingpin_damping_nms_per_rad"),
            f("tie_rod_stiffness_n_per_m"), f("restraint_stiffness_n_per_m"),
            f("restraint_damping_ns_per_m"),
            (math.log(u) - 0.5 * math.log(uhi * ulo)) / (0.5 * math.log(uhi / ulo)),
            (2 * n - nlo - nhi) / (nhi - nlo)] + [
        lin(p[f"column.{k}"], *COLUMN[k]) for k in
        ("inertia_kgm2", "torsion_bar_nm_per_rad", "torsion_bar_damping_nms_per_rad")]


class Law:
    """The table's nuisance law and its covariances (src/observer/linear.rs)."""

    def __init__(self, path):
        t = json.load(open(path))
        lm = t["linear"]
        self.prior = t["prior"]
        self.lnc = np.log(np.array(t["clearance_mm"]))
        self.v = np.array(t["speed_kmh"])
        self.terms = [self.parse(s) for s in lm["terms"]]
        self.coef = np.array(lm["coef"]).reshape(len(self.lnc), len(self.v), 3, len(self.terms))
        self.within = np.array(lm["within"])
        self.between = np.array(lm["between"])

    @staticmethod
    def parse(s):
        exp, dec = [0] * 11, 0
        if s != "1":
            for f in s.split("*"):
                name, pw = (f.split("^") + ["1"])[:2]
                if name == "d":
                    dec = int(pw)
                elif name == "u":
                    exp[10] = int(pw)
                else:
                    exp[int(name[1:])] = int(pw)
        return exp, dec

    def _at(self, arr, c_mm):
        y = math.log(c_mm)
        i = min(max(bisect.bisect(self.lnc, y) - 1, 0), len(self.lnc) - 2)
        w = min(max((y - self.lnc[i]) / (self.lnc[i + 1] - self.lnc[i]), 0.0), 1.0)
        return (1 - w) * arr[i] + w * arr[i + 1]

    def ln_likelihood_draws(self, c_mm, events, basis):
        """ln p(events | c, draw k) for every draw: `basis[k, e, t]` the law's monomials."""
        cf = self._at(self.coef, c_mm)
        rows = []
        for v, _, _, _ in events:
            j = min(max(bisect.bisect(self.v, v) - 1, 0), len(self.v) - 2)
            wv = min(max((v - self.v[j]) / (self.v[j + 1] - self.v[j]), 0.0), 1.0)
            rows.append((1 - wv) * cf[j] + wv * cf[j + 1])
        z = np.array([e[3] for e in events])
        r = z[None] - np.einsum("ket,eft->kef", basis, np.array(rows))
        w = self._at(self.within, c_mm)
        bt = self._at(self.between, c_mm) + 1e-6 * np.eye(3)
        wi = np.linalg.inv(w)
        k = len(events)
        s = r.sum(1) @ wi
        m = np.linalg.inv(np.linalg.inv(bt) + k * wi)
        return (-0.5 * np.einsum("kei,ij,kej->k", r, wi, r)
                + 0.5 * np.einsum("ki,ij,kj->k", s, m, s)
                - 0.5 * np.linalg.slogdet(np.eye(3) + k * bt @ wi)[1]
                - 0.5 * k * np.linalg.slogdet(w)[1])

    def basis_draws(self, draws, events, events_psi=False):
        """The monomials of every draw (10 coordinates and ψ) at every event's deceleration;
        with `events_psi` each event's own ψ instead of the draw's."""
        out = np.ones((len(draws), len(events), len(self.terms)))
        if events_psi:
            draws = draws.copy()
        for e, (_, decel_g, psi, _) in enumerate(events):
            dn = (decel_g - 0.55) / 0.25
            if events_psi:
                draws[:, 10] = psi
            for t, (exp, d) in enumerate(self.terms):
                col = np.full(len(draws), dn ** d)
                for i, ex in enumerate(exp):
                    if ex:
                        col = col * draws[:, i] ** ex
                out[:, e, t] = col
        return out


def prior_draws(n):
    """n draws of the ten coordinates (uniform) and ψ = cos of a uniform phase."""
    rng = np.random.default_rng(20261207)
    return np.concatenate([rng.uniform(-1, 1, size=(n, 10)),
                           np.cos(rng.uniform(0, 2 * math.pi, size=(n, 1)))], axis=1)


def features(t):
    z = lambda x, f: 0.5 * math.log(x * x + f * f)
    return np.array([z(t["rms_bp_nm"], FLOOR[0]), z(t["peak_bp_nm"], FLOOR[1]),
                     z(t["cruise_rms_bp_nm"], FLOOR[0])])


def vehicle_events(fleet, seed, profile):
    est = os.path.join(fleet, f"est_{seed}.json")
    if not os.path.exists(est):
        with open(est, "w") as out:
            subprocess.run([os.path.join(ROOT, "target/release/shimmy"), "estimate", "--profile",
                            profile, "--config", os.path.join(ROOT, "config/observer.toml"),
                            os.path.join(fleet, f"fleet_{seed}.log")], stdout=out, check=True)
    truth = json.load(open(os.path.join(fleet, f"fleet_{seed}.truth.json")))["events"]
    out = []
    for ev in json.load(open(est))["events"]:
        t = ev.get("torque")
        if not ev["used"] or not t or not t.get("used", True):
            continue
        # the truth event of this one: the nearest start speed and deceleration
        te = min(truth, key=lambda e: abs(e["v0_kmh"] - ev["v0_kmh"])
                 + 100 * abs(e["decel_g"] - ev["decel_g"]))
        out.append((ev["v0_kmh"], ev["decel_g"], te["unbalance_phase_cos"], features(t)))
    return out


def fleet_likelihoods(law, fleet, profile, nominal, draws):
    """Per vehicle: truth, the fleet's estimate, its final P(c > 0.1 mm), ln L over GRID ×
    (damping grid, true) and ln L over GRID with every coordinate and ψ integrated out."""
    cache = fleet + ".oracle.npz"
    if os.path.exists(cache):
        d = np.load(cache)
        if "mc" in d and d["n_draws"] == len(draws):
            return list(zip(d["c"], d["median"], d["alert"], d["p_final"], d["ll"], d["mc"]))
    rows = []
    vehicles = json.load(open(fleet + ".json"))["vehicles"]
    for i, v in enumerate(vehicles):
        seed = v["seed"]
        x0 = coords(toml_numbers(os.path.join(fleet, f"vehicle_{seed}.toml")), nominal, law.prior)
        events = vehicle_events(fleet, seed, profile)
        # the damping grid's points and the true coordinates, each event's true ψ
        known = np.array([list(x0) + [0.0]] * (len(DAMPING_GRID) + 1))
        known[:-1, 1] = DAMPING_GRID
        basis_known = law.basis_draws(known, events, events_psi=True)
        ll = np.array([law.ln_likelihood_draws(c, events, basis_known) for c in GRID])
        basis = law.basis_draws(draws, events)
        mc = np.full(len(GRID), np.nan if len(draws) == 0 else 0.0)
        for gi, c in enumerate(GRID if len(draws) else []):
            l = law.ln_likelihood_draws(c, events, basis)
            mc[gi] = l.max() + math.log(np.exp(l - l.max()).mean())
        rows.append((v["clearance_true_mm"], v["median_mm"], bool(v["clearance_alert"]),
                     v.get("p_clearance_above_threshold") or 0.0, ll, mc))
        print(f"{fleet}: {i + 1}/{len(vehicles)}", file=sys.stderr)
    np.savez(cache, c=[r[0] for r in rows], median=[r[1] for r in rows],
             alert=[r[2] for r in rows], p_final=[r[3] for r in rows],
             ll=np.array([r[4] for r in rows]), mc=np.array([r[5] for r in rows]),
             n_draws=len(draws))
    return rows


def score(rows, post):
    mae, worn, false, band, cover = [], [0, 0], [0, 0], [0, 0], 0
    for c, _, _, _, ll, mc in rows:
        lp = post(ll, mc)
        p = np.exp(lp - lp.max())
        p /= p.sum()
        cdf = np.cumsum(p)
        q = lambda x: GRID[min(np.searchsorted(cdf, x), len(GRID) - 1)]
        alert = p[GRID > 0.1].sum() >= 0.7
        cover += q(0.05) <= c <= q(0.95)
        if c >= 0.1:
            mae.append(abs(q(0.5) - c))
        for lo, hi, acc in ((0.15, 9, worn), (0, 0.0700001, false), (0.0700001, 0.1, band)):
            if lo <= c < hi:
                acc[0] += alert
                acc[1] += 1
    return worn, false, band, cover, (np.mean(mae) if mae else float("nan"))


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--table", required=True)
    ap.add_argument("--profile", required=True)
    ap.add_argument("--power", type=float, default=0.2, help="the shipped evidence power")
    ap.add_argument("--mc", type=int, default=2048,
                    help="prior draws for the 'nothing known' oracle")
    ap.add_argument("fleets", nargs="+")
    a = ap.parse_args()
    law = Law(a.table)
    nominal = toml_numbers(os.path.join(ROOT, "config/vehicle/default.toml"))
    draws = prior_draws(a.mc)
    rows = [r for f in a.fleets for r in fleet_likelihoods(law, f, a.profile, nominal, draws)]

    def damping_unknown(ll):
        m = ll[:, :-1]
        top = m.max(1)
        return top + np.log(np.exp(m - top[:, None]).mean(1))

    print("| who | worn alerted c ≥ 0.15 | false c ≤ 0.07 | false 0.07–0.1 | 90 % coverage "
          "| MAE c ≥ 0.1 (mm) |")
    print("|---|---|---|---|---|---|")
    for pw in (1.0, a.power):
        for name, post in ((f"vehicle known, power {pw}", lambda ll, mc: pw * ll[:, -1]),
                           (f"kingpin damping unknown, power {pw}",
                            lambda ll, mc: pw * damping_unknown(ll)),
                           (f"nothing known, prior integrated exactly, power {pw}",
                            lambda ll, mc: pw * mc))[:3 if a.mc else 2]:
            w, f, b, cov, mae = score(rows, post)
            print(f"| {name} | {w[0]}/{w[1]} | {f[0]}/{f[1]} | {b[0]}/{b[1]} "
                  f"| {cov}/{len(rows)} | {mae:.3f} |")
    est = lambda lo, hi: (sum(r[2] for r in rows if lo <= r[0] < hi),
                          sum(1 for r in rows if lo <= r[0] < hi))
    err = [abs(r[1] - r[0]) for r in rows if r[0] >= 0.1]
    mae = np.mean(err) if err else float("nan")
    print("| the estimator (nothing known), alert standing at the end | %d/%d | %d/%d | %d/%d | | %.3f |"
          % (*est(0.15, 9), *est(0, 0.0700001), *est(0.0700001, 0.1), mae))
    fin = lambda lo, hi: (sum(r[3] >= 0.7 for r in rows if lo <= r[0] < hi),
                          sum(1 for r in rows if lo <= r[0] < hi))
    print("| the estimator, final P(c > 0.1 mm) >= 0.7 | %d/%d | %d/%d | %d/%d | | |"
          % (*fin(0.15, 9), *fin(0, 0.0700001), *fin(0.0700001, 0.1)))


if __name__ == "__main__":
    main()
