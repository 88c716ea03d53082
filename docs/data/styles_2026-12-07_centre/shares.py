import csv, sys
from lmpc_bridge.evaluation.style import direction_shares, style_summary, style_table_md
def num(v):
    try: return float(v)
    except (TypeError, ValueError): return v
rows = []
for f in sys.argv[1:]:
    rows += [{k: num(v) for k, v in r.items()} for r in csv.DictReader(open(f))]
print(style_table_md(style_summary(rows), direction_shares(rows)))
