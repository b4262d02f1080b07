"""Does any vehicle-level summary of the steering angle predict the estimator's error? (docs/ACCURACY.md)

Not part of the product. For every vehicle of one or more `firmware-sim fleet` runs, reads the
candump log (SAS_Angle, id 0x0A0, 0.1 deg, of dbc/shimmy_reference.dbc) and the ground truth's
event windows, band-passes 3-25 Hz (FFT mask) and summarises the vehicle's events:
  lnrms         mean ln RMS over the braking windows
  crest         mean ln(peak / RMS)
  cruise        mean ln RMS over 1.2 s before the brake onset (0.05 s guard)
  brk_minus_cruise, early_late (ln RMS first half - second half of the window),
  lnrms_lo_v / lnrms_hi_v (events starting below 50 / above 70 km/h),
  slope_v / slope_d (slope of ln RMS over v0 / deceleration), sd_lnrms, frac_loud (RMS > 0.06 deg),
  rice_hz       mean of RMS(dy/dt) / (2 pi RMS(y)), the band's mean frequency
  centroid_hz   mean spectral centroid (Hann window) in the band
Then, over all vehicles, the residual ln c_true - ln c_estimate of the fleet's `--json` file:
its correlation with each summary (all vehicles and c >= 0.1 mm), and the leave-one-vehicle-out
MAE (c >= 0.1 mm) of a linear re-calibration ln c ~ 1 + ln estimate (+ the summary). A summary
that carries what the estimator misses lowers that MAE; one that does not raises it a little
(one more fitted coefficient).

Usage (numpy): python3 docs/experiments/residual_screen.py FLEET.json WORKDIR [FLEET.json WORKDIR ...]
"""
import glob
import json
import os
import sys

import numpy as np

FS = 100.0


def bandpass(x, lo=3.0, hi=25.0):
    spec = np.fft.rfft(x - x.mean())
    f = np.fft.rfftfreq(len(x), 1 / FS)
    spec[(f < lo) | (f > hi)] = 0
    return np.fft.irfft(spec, len(x))


def angle_samples(log, t0):
    ts, an = [], []
    with open(log) as fh:
        for line in fh:
            if " 0A0#" not in line:
                continue
            data = line.split("#")[1].strip()
            raw = int(data[2:4] + data[0:2], 16)
            raw -= 65536 if raw >= 32768 else 0
            ts.append(float(line[1 : line.index(")")]) - t0)
            an.append(raw * 0.1)
    return np.array(ts), np.array(an)


def ln(x):
    return np.log(max(x, 1e-3))


def vehicle(truth_path):
    t = json.load(open(truth_path))
    ts, an = angle_samples(truth_path.replace(".truth.json", ".log"), t["start_unix_s"])
    ev = []
    for e in t["events"]:
        a, b = e["window_s"]
        m = (ts >= a - 2.0) & (ts <= b)
        y, tt = bandpass(an[m]), ts[m]
        yb = y[tt >= a]
        cr = (tt >= a - 1.25) & (tt < a - 0.05) & (tt >= a - 1.6)
        r = np.sqrt(np.mean(yb**2))
        half = len(yb) // 2
        rice = np.sqrt(np.mean((np.diff(yb) * FS) ** 2)) / (2 * np.pi * r) if r > 0 else np.nan
        sp = np.abs(np.fft.rfft(yb * np.hanning(len(yb)))) ** 2
        f = np.fft.rfftfreq(len(yb), 1 / FS)
        band = (f >= 3) & (f <= 25)
        cen = (f[band] * sp[band]).sum() / sp[band].sum() if sp[band].sum() > 0 else np.nan
        ev.append(
            (
                e["v0_kmh"],
                e["decel_g"],
                ln(r),
                ln(np.abs(yb).max()),
                ln(np.sqrt(np.mean(y[cr] ** 2))) if cr.sum() > 30 else np.nan,
                ln(np.sqrt(np.mean(yb[:half] ** 2))) - ln(np.sqrt(np.mean(yb[half:] ** 2))),
                rice,
                cen,
            )
        )
    ev = np.array(ev)
    v0, dg, lr = ev[:, 0], ev[:, 1], ev[:, 2]
    return t["scenario"]["seed"], t["clearance"]["left_mm_start"], {
        "lnrms": lr.mean(),
        "crest": (ev[:, 3] - lr).mean(),
        "cruise": np.nanmean(ev[:, 4]),
        "brk_minus_cruise": np.nanmean(lr - ev[:, 4]),
        "early_late": ev[:, 5].mean(),
        "lnrms_lo_v": lr[v0 < 50].mean() if (v0 < 50).any() else np.nan,
        "lnrms_hi_v": lr[v0 > 70].mean() if (v0 > 70).any() else np.nan,
        "slope_v": np.polyfit(v0, lr, 1)[0],
        "slope_d": np.polyfit(dg, lr, 1)[0],
        "sd_lnrms": lr.std(),
        "frac_loud": float(np.mean(lr > np.log(0.06))),
        "rice_hz": np.nanmean(ev[:, 6]),
        "centroid_hz": np.nanmean(ev[:, 7]),
    }


def main(args):
    c, est, summaries = [], [], []
    for fleet_json, work_dir in zip(args[::2], args[1::2]):
        by_seed = {v["seed"]: v for v in json.load(open(fleet_json))["vehicles"]}
        for p in sorted(glob.glob(os.path.join(work_dir, "fleet_*.truth.json"))):
            seed, c_true, s = vehicle(p)
            if by_seed.get(seed, {}).get("median_mm") is None:
                continue
            c.append(c_true)
            est.append(by_seed[seed]["median_mm"])
            summaries.append(s)
    c, est = np.array(c), np.array(est)
    y = np.log(c)
    res = y - np.log(est)
    big = c >= 0.1

    def loo_mae(cols):
        x = np.column_stack([np.ones(len(y))] + cols)
        pred = np.zeros(len(y))
        for i in range(len(y)):
            keep = np.arange(len(y)) != i
            beta = np.linalg.lstsq(x[keep], y[keep], rcond=None)[0]
            pred[i] = x[i] @ beta
        return np.mean(np.abs(np.exp(pred[big]) - c[big]))

    print(f"{len(c)} vehicles, {big.sum()} with c >= 0.1 mm")
    print(f"estimator MAE (c >= 0.1): {np.mean(np.abs(est[big] - c[big])):.4f}")
    print(f"LOO re-calibrated on ln estimate alone: {loo_mae([np.log(est)]):.4f}")
    print("summary            corr(residual): all  c>=0.1   LOO MAE with it")
    for k in summaries[0]:
        x = np.array([s[k] for s in summaries])
        x = np.where(np.isnan(x), np.nanmean(x), x)
        print(
            f"{k:<18} {np.corrcoef(res, x)[0, 1]:+.2f}  {np.corrcoef(res[big], x[big])[0, 1]:+.2f}"
            f"    {loo_mae([np.log(est), x]):.4f}"
        )


if __name__ == "__main__":
    main(sys.argv[1:])
