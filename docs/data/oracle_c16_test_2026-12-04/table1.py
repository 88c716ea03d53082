"""Table I rows of lmpc-oracle per family (the README's columns), from the repository root:
python3 docs/data/oracle_c16_test_2026-12-04/table1.py FAMILY=RESULTS.csv[,MORE.csv] ...
(a scene in several files: the last one's row); vs MPC against Table I's mpc rows."""
import csv, statistics, sys
ref = {(r['family'], int(r['seed']), r['method']): r
       for r in csv.DictReader(open('docs/data/latency_2026-12-04/t1/results.csv'))}
for arg in sys.argv[1:]:
    fam, _, files = arg.partition('=')
    rows = {int(r['seed']): r for f in files.split(',') for r in csv.DictReader(open(f))
            if r['family'] == fam and r['method'] == 'lmpc-oracle'}
    rows = [rows[s] for s in sorted(rows)]
    mean = lambda k: statistics.fmean(float(r[k]) for r in rows)
    mpc = statistics.fmean(float(ref[(fam, int(r['seed']), 'mpc')]['overall_cost']) for r in rows)
    coll = sum(int(r['collision']) for r in rows)
    fail = sum(int(r['fail']) for r in rows)
    oc = mean('overall_cost')
    print(f"| {fam.upper()} | lmpc-oracle | {coll} | {fail} | {mean('ineff'):.1f} | {mean('time_s'):.1f} | "
          f"{mean('pen_acc'):.2f} | {mean('pen_dist'):.2f} | {oc:.1f} | {(oc / mpc - 1) * 100:+.1f} % |  "
          f"(n={len(rows)})")
