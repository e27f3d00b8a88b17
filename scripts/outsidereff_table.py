"""Before → after of branch outsidereff on the outsider seeds 12/13 (docs/measurements/outsidereff.md):
the stored rows of outsider2 overlaid with the re-run tach cases.

    .venv/bin/python scripts/outsidereff_table.py
"""
import json, glob, collections
from scipy.stats import beta
def cp(k, n):
    lo = 0.0 if k == 0 else beta.ppf(0.025, k, n - k + 1)
    hi = 1.0 if k == n else beta.ppf(0.975, k + 1, n - k)
    return f"{k}/{n} ({100*lo:.1f}–{100*hi:.1f} %)"
rows = {}
for pat in ['before', 'after']:
    for f in sorted(glob.glob(f'docs/measurements/outsider2/{pat}.s*.jsonl')):
        for l in open(f):
            r = json.loads(l); rows[r['name']] = r
new = {json.loads(l)['name']: json.loads(l) for l in open('docs/measurements/outsidereff/tach.s12s13.jsonl')}
closed_measured = {k: v for k, v in new.items() if v['excitation'] == 'closed'}
new = {k: v for k, v in new.items() if v['excitation'] != 'closed'}  # closed loop kept out of the switch
# A voltage or duty command held on levels (staircase, PRBS staircase) keeps its speed (a PWM
# bridge's per-level error): those rows are integ3's too.
pwm = {k: v for k, v in new.items() if rows[k]['spec']['unit'] in ('V', 'duty') and v['excitation'] in ('staircase', 'prbs')}
new = {k: v for k, v in new.items() if k not in pwm}
for loop in ('open', 'closed'):
    nl = [r for r in rows.values() if r['spec']['cause'] == 'none' and (r['spec']['excitation'] == 'closed') == (loop == 'closed')]
    b = sum(r['cause'] != 'none' for r in nl)
    a = sum((new[r['name']]['after'] if r['name'] in new else r['cause']) != 'none' for r in nl)
    sw = sum(new.get(r['name'], {}).get('switched', False) for r in nl)
    print(f"{loop} nulls: before {cp(b, len(nl))}  after {cp(a, len(nl))}  switched {sw}  (tach rerun {sum(r['name'] in new for r in nl)})")
print()
tab = collections.defaultdict(lambda: [0, 0, 0])
for r in rows.values():
    s = r['spec']
    if s['cause'] == 'none' or s['excitation'] == 'closed':
        continue
    after = new[r['name']]['after'] if r['name'] in new else r['cause']
    k = (s['cause'], s['size'])
    tab[k][0] += 1; tab[k][1] += r['cause'] == s['cause']; tab[k][2] += after == s['cause']
    if (r['cause'] == s['cause']) != (after == s['cause']) or after != s['cause']:
        print(r['name'], s['cause'], s['size'], s['sensor']['omega'], r['cause'], '->', after, new.get(r['name'], {}).get('top'))
print()
tot = [sum(v[i] for v in tab.values()) for i in range(3)]
print('open-loop effects named', f'{tot[1]}/{tot[0]} -> {tot[2]}/{tot[0]}')
for k in sorted(tab):
    print(k, f"{tab[k][1]}/{tab[k][0]} -> {tab[k][2]}/{tab[k][0]}")

print()
print('V/duty held on levels, had the switch applied (measured, then excluded):')
pn = [r for r in pwm.values() if r['truth'] == 'none']
print(f"  nulls {len(pn)}, switched {sum(r['switched'] for r in pn)}, named after {sum(r['after'] != 'none' for r in pn)}")
for r in pwm.values():
    if r['truth'] != 'none' and r['switched']:
        print('  ', r['name'], r['truth'], r['size'], r['before'], '->', r['after'])
print()
print('closed loop, had the switch applied (measured, then excluded):')
cn = [r for r in closed_measured.values() if r['truth'] == 'none']
print(f"  tach nulls {len(cn)}, switched {sum(r['switched'] for r in cn)}, named after {sum(r['after'] != 'none' for r in cn)}")
for r in closed_measured.values():
    if r['truth'] != 'none':
        print('  ', r['name'], r['truth'], r['size'], r['before'], '->', r['after'], r['switched'])
