import csv, glob, sys
from collections import defaultdict
def load(paths, method, seeds=range(10)):
    d={}
    for p in paths:
        for r in csv.DictReader(open(p)):
            if r['method']==method and int(r['seed']) in seeds:
                d[(r['family'],int(r['seed']))]=r
    return d
new=load([sys.argv[1]],'lmpc-oracle')
o0=load(glob.glob('/work/main/docs/data/oracle_c16_test_2026-12-04/results_*.csv'),'lmpc-oracle')
r0=load(['/work/main/docs/data/latency_2026-12-04/t1/results.csv'],'lmpc-rules')
r25=load(['/work/main/docs/data/latency_2026-12-04/p2.5/results.csv'],'lmpc-rules')
m0=load(['/work/main/docs/data/latency_2026-12-04/t1/results.csv'],'mpc')
fams=sorted({k[0] for k in new})
for f in fams:
    keys=sorted(k for k in new if k[0]==f)
    def cell(d):
        rs=[d[k] for k in keys if k in d]
        bad=sum(int(r['collision'] or 0) for r in rs), sum(int(r['fail'] or 0) for r in rs)
        return f"{bad[0]}+{bad[1]} {sum(float(r['overall_cost']) for r in rs)/len(rs):.1f} ({len(rs)})"
    print(f, 'seeds', [k[1] for k in keys])
    print('  mpc', cell(m0), '| rules 0', cell(r0), '| rules 2.5', cell(r25), '| oracle 0', cell(o0), '| oracle 2.5', cell(new))
