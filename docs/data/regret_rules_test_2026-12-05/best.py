"""Per family: which option was best when the regret was > 0, by mode; regret sum per scene."""
import csv, sys, collections, math
rows = list(csv.DictReader(open(sys.argv[1])))
for fam in sorted({r['family'] for r in rows}):
    rs = [r for r in rows if r['family'] == fam]
    pos = [r for r in rs if float(r['regret']) > 0]
    fin = [r for r in pos if math.isfinite(float(r['regret']))]
    tot = sum(float(r['regret']) for r in fin)
    by_best = collections.Counter(r['best'] for r in pos)
    reg_best = collections.defaultdict(float)
    for r in fin: reg_best[r['best']] += float(r['regret'])
    by_mode = collections.defaultdict(float)
    for r in fin: by_mode[r['mode']] += float(r['regret'])
    modes = collections.Counter(r['mode'] for r in rs)
    print(fam, 'decisions', len(rs), 'with regret', len(pos), 'inf', len(pos)-len(fin), 'sum', round(tot,1))
    print('  best (count, share of regret):', ', '.join(f"{k} {v} ({reg_best[k]/tot:.0%})" for k, v in by_best.most_common(6)))
    print('  regret by mode:', {m: f"{by_mode[m]/tot:.0%} of regret, {modes[m]} decisions" for m in modes})
