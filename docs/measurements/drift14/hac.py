import sys, itertools, json
import numpy as np
sys.path.insert(0, "/work/wt/drift14/scripts")
from tvsd.analysis import absorber, drift, speed_source
from tvsd.analysis import calibrate as C
from tvsd.analysis import design as D
from tvsd.analysis.dataset import load
from tvsd.analysis.prep import Band, prepare
from tvsd.analysis.gls import whiten
from tvsd.config import load_config

def setup(path):
    data = speed_source.choose(load(path, load_config()), Band())
    prep = prepare(data, Band())
    design = absorber.absorb(D.build(prep, data.offset_term, True))
    out = C.test_all(design)
    return design, out

def windows_hac(design, out, parameter, block_s, k=10):
    t = design.prep.t_rows
    t0, t1 = float(t[0]), float(t[-1])
    edges = np.linspace(t0, t1 + 1e-9, k + 1)
    cols = drift._split_columns(design, parameter)
    shared = [j for j in range(design.X.shape[1]) if j not in cols]
    blocks, centres = [], []
    for lo, hi in itertools.pairwise(edges):
        inside = (t >= lo) & (t < hi)
        blocks.append(design.X[:, cols] * inside[:, None]); centres.append((0.5*(lo+hi)-t0)/(t1-t0))
    X = np.column_stack([design.X[:, shared], *blocks])
    yw, Xw = whiten(design.y, out.ar, out.keep), whiten(X, out.ar, out.keep)
    tk = t[out.keep]
    th, *_ = np.linalg.lstsq(Xw, yw, rcond=None)
    r = yw - Xw @ th
    n, p = Xw.shape
    Minv = np.linalg.pinv(Xw.T @ Xw)
    cov_gls = r @ r / (n - p) * Minv
    # scores summed over time blocks of block_s
    bid = np.floor((tk - t0) / block_s).astype(int)
    S = np.zeros((p, p))
    for b in np.unique(bid):
        s = Xw[bid == b].T @ r[bid == b]
        S += np.outer(s, s)
    cov_hac = Minv @ S @ Minv
    m, w = len(shared), len(cols)
    L = np.zeros((k, p))
    for i in range(k):
        L[i, m + i*w: m + (i+1)*w] = 1
    return np.array(centres), L @ th, L @ cov_gls @ L.T, L @ cov_hac @ L.T

for path in sys.argv[1:]:
    design, out = setup(path)
    dt = [t for t in out.tested if t.cause == "drift"][0]
    par = str(dt.option.effect["parameter"]); sign = float(dt.coef[0])
    res = {"file": path[-10:], "z": round(dt.z, 2), "thr": round(out.threshold, 2), "par": par}
    for bs in (0.004, 0.5, 1.0, 2.0, 3.0):
        c, e, Sg, Sh = windows_hac(design, out, par, bs)
        tr_g = drift.trend(c, e, Sg, sign); tr_h = drift.trend(c, e, Sh, sign)
        res[f"b{bs}"] = dict(se_ratio=round(float(np.median(np.sqrt(np.diag(Sh)/np.diag(Sg)))), 2), t_gls=round(tr_g.t, 2), phi_gls=round(tr_g.phi, 2), t_hac=round(tr_h.t, 2), phi_hac=round(tr_h.phi, 2))
    print(json.dumps(res), flush=True)
