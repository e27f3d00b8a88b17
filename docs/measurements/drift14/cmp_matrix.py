import json, glob, sys
from collections import defaultdict
def rows(p): return {r['seed']: r for f in glob.glob(p) for l in open(f) for r in [json.loads(l)]}
tab = defaultdict(lambda: [0,0,0])
for pat in sys.argv[1:]:
    b, a = rows(pat.replace('X','before')), rows(pat.replace('X','after'))
    for s in sorted(b):
        rb, ra = b[s], a[s]
        vis = rb['seen'].get('visible')
        for k in [f"{rb['size']:g}x", ('>=1u' if vis >= 1 else '<1u')]:
            tab[k][0]+=1; tab[k][1]+= rb['ls']=='drift'; tab[k][2]+= ra['ls']=='drift'
        if rb['ls'] != ra['ls']: print('CHANGED', s, rb['effect'], rb['profile'], 'vis', vis, rb['ls'], '->', ra['ls'], ra['ls_why']['z'].get('drift'))
for k,v in sorted(tab.items()): print(k, f"{v[1]}/{v[0]} -> {v[2]}/{v[0]}")
