"""The oracle's rows beside Table I's mpc and lmpc-rules rows (latency 0, main of
2026-12-04), from the repository root: python3 docs/data/oracle_test_2026-12-04/compare.py
docs/data/oracle_test_2026-12-04/results*.csv (every result file of the folder; a scene in
several files: the last one's row)."""
import csv, statistics, sys
ref = {}
for r in csv.DictReader(open('docs/data/latency_2026-12-04/t1/results.csv')):
    ref[(r['family'], int(r['seed']), r['method'])] = r
orc = {(r['family'], int(r['seed'])): r for f in sys.argv[1:] for r in csv.DictReader(open(f))}
print('| Scenario | seed | mpc | lmpc-rules | lmpc-oracle |')
print('|---|---|---|---|---|')
fams = ['si', 'usi', 'lane', 'rab', 'eoa']
cell = lambda r: f"{r['outcome']} {float(r['time_s']):.1f} s, {float(r['overall_cost']):.1f}"
for f in fams:
    for s in range(25):
        if (f, s) not in orc: continue
        print(f"| {f.upper()} | {s} | {cell(ref[(f,s,'mpc')])} | {cell(ref[(f,s,'lmpc-rules')])} | {cell(orc[(f,s)])} |")
for f in fams:
    ss = [s for s in range(25) if (f, s) in orc]
    if not ss:
        continue
    m = statistics.fmean(float(ref[(f,s,'mpc')]['overall_cost']) for s in ss)
    r = statistics.fmean(float(ref[(f,s,'lmpc-rules')]['overall_cost']) for s in ss)
    o = statistics.fmean(float(orc[(f,s)]['overall_cost']) for s in ss)
    lose = sum(float(orc[(f,s)]['overall_cost']) > float(ref[(f,s,'mpc')]['overall_cost']) for s in ss)
    fails = sum(int(orc[(f,s)]['fail']) + int(orc[(f,s)]['collision']) for s in ss)
    print(f"{f}: n={len(ss)} mpc {m:.1f} rules {r:.1f} ({(r/m-1)*100:+.1f} %) oracle {o:.1f} ({(o/m-1)*100:+.1f} %) oracle>mpc in {lose}, oracle coll+fail {fails}")
allss=[(f,s) for f in fams for s in range(25) if (f,s) in orc]
m = statistics.fmean(float(ref[(f,s,'mpc')]['overall_cost']) for f,s in allss)
r = statistics.fmean(float(ref[(f,s,'lmpc-rules')]['overall_cost']) for f,s in allss)
o = statistics.fmean(float(orc[k]['overall_cost']) for k in allss)
print(f"all n={len(allss)}: mpc {m:.1f} rules {r:.1f} ({(r/m-1)*100:+.1f} %) oracle {o:.1f} ({(o/m-1)*100:+.1f} %)")
