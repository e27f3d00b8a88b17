import numpy as np, sys
sys.path.insert(0, "/work/wt/drift14/tests")
import outsider_bench as ob
s = ob.draw(14042, "none", 0.0)
d = np.loadtxt("/work/wt/outsider14/set/o14042.csv", delimiter=",", comments="#", skiprows=5)
t, u = d[:, 0], d[:, 1]
top = s.drive["u_top"]; q = 1.3 * top / 2 ** (s.drive["pwm_bits"] - 1)
ua = np.round(u / q) * q
print("q", q, "top", top)
est = [21.635364, 21.655935, 21.682157, 21.527921, 21.489109, 21.627593, 21.425183, 21.346096, 21.432951, 21.492215]
edges = np.linspace(t[0], t[-1] + 1e-9, 11)
g = []
for i in range(10):
    m = (t >= edges[i]) & (t < edges[i + 1])
    # the gain of the applied command on the recorded one, and on its fluctuations (PRBS part)
    g.append(float(ua[m] @ u[m] / (u[m] @ u[m])))
g = np.array(g); e = np.array(est)
print("window gain of quantiser", np.round(g, 4))
print("window est / mean", np.round(e / e.mean(), 4))
print("corr", np.corrcoef(g, e)[0, 1])
x = np.arange(10)
print("slope quantiser gain over record", np.polyfit(x / 9, g, 1)[0], "est rel", np.polyfit(x / 9, e / e.mean(), 1)[0])
