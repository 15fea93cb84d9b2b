#!/usr/bin/python3
"""How well one run measures the cover's trend (issue 39): for each JSON record of
tools/cloud_stats.py (--json), the cover's mean, spread, trend / mean, the residual's integral
time scale tau (1 + 2 x the sum of its autocorrelation up to the first zero, times the snapshot
interval), and the standard error of trend / mean for a series of window / tau independent
samples.

    /usr/bin/python3 docs/data/bomex/trend_noise.py RECORD.json [RECORD.json...]
"""
import json, sys, numpy as np
for f in sys.argv[1:]:
    r = json.load(open(f)); t = np.array(r['series']['time']); c = np.array(r['series']['cover'])
    T = t[-1] - t[0]; m = c.mean()
    A = np.vstack([t - t.mean(), np.ones_like(t)]).T
    coef, *_ = np.linalg.lstsq(A, c, rcond=None)
    res = c - A @ coef
    rho = np.corrcoef(res[:-1], res[1:])[0, 1]
    # integral time scale from the residual's autocorrelation up to its first zero
    ac = [1.0]
    for k in range(1, len(res) // 2):
        a = np.corrcoef(res[:-k], res[k:])[0, 1]
        if a <= 0: break
        ac.append(a)
    tau = (1 + 2 * sum(ac[1:])) * (t[1] - t[0])
    se_white = res.std(ddof=2) / np.sqrt(((t - t.mean()) ** 2).sum())
    neff = T / tau
    se = se_white * np.sqrt(len(t) / max(neff, 1))
    print(f"{f.split('/')[-1]:22s} mean {m:.3f} sd {c.std():.3f} (sd/mean {c.std()/m:.2f}) trend/mean {coef[0]*T/m:+.2f}  "
          f"lag-1 {rho:.3f} tau {tau/60:.0f} min  n_eff {neff:.1f}  s.e. of trend/mean {se*T/m:.2f}")
