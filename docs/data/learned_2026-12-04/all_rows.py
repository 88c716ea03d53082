"""Table I with every row: mpc + lmpc-rules (t1) and dqn, ppo, sac, adp; the paper's O.C.
change vs MPC beside ours. Since 2026-12-05 the code is ../rl_2026-12-05/table1.py (the
same table, with a per-file method filter); this name is kept for the commands above."""
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "rl_2026-12-05"))
from table1 import main  # noqa: E402

if __name__ == "__main__":
    main()
