"""``lmpc-replay`` in the benchmark repeats a finished run's decisions from its logs and
says whether each scene repeats the recorded row exactly; a log that no longer holds
the prompts the code asks (here: one prompt hash altered) is reported as differing."""
from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
BENCH = [sys.executable, str(REPO / "scripts" / "benchmark.py"), "--families", "usi",
         "--seeds", "0", "--workers", "1"]


def _bench(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([*BENCH, *args], capture_output=True, text=True, timeout=300)


def test_replay_of_a_recorded_run_is_an_exact_repeat_and_a_stale_log_is_not(
        tmp_path: Path) -> None:
    rec = _bench("--methods", "lmpc-rules", "--out", str(tmp_path / "rec"))
    assert rec.returncode == 0, rec.stdout[-2000:] + rec.stderr[-2000:]

    rep = _bench("--methods", "lmpc-replay", "--replay-from", str(tmp_path / "rec"),
                 "--replay-of", "lmpc-rules", "--out", str(tmp_path / "rep"))
    assert rep.returncode == 0, rep.stdout[-2000:] + rep.stderr[-2000:]
    report = (tmp_path / "rep" / "replay_check.txt").read_text()
    assert report.splitlines()[0].endswith("1 of 1 scene(s) repeat the recorded row exactly")
    assert "usi seed 0: exact repeat: 0 of " in report

    # Alter the prompt hash of the last recorded call: the replay cannot answer it.
    log = tmp_path / "rec" / "decisions" / "usi-000-lmpc-rules.jsonl"
    records = [json.loads(line) for line in log.read_text().splitlines()]
    assert len(records) >= 3
    records[-1]["attempts"][0]["prompt_sha256"] = "0" * 64
    log.write_text("".join(json.dumps(r) + "\n" for r in records))
    stale = _bench("--methods", "lmpc-replay", "--replay-from", str(tmp_path / "rec"),
                   "--replay-of", "lmpc-rules", "--out", str(tmp_path / "stale"))
    assert stale.returncode == 0, stale.stdout[-2000:] + stale.stderr[-2000:]
    report = (tmp_path / "stale" / "replay_check.txt").read_text()
    assert report.splitlines()[0].endswith("0 of 1 scene(s) repeat the recorded row exactly")
    missed = re.search(r"usi seed 0: differs: (\d+) of (\d+) prompt", report)
    assert missed is not None, report
    assert 1 <= int(missed.group(1)) < int(missed.group(2))


def test_replay_without_a_run_folder_is_refused_naming_the_option(tmp_path: Path) -> None:
    res = _bench("--methods", "lmpc-replay", "--out", str(tmp_path / "x"))
    assert res.returncode == 2
    assert "lmpc-replay needs --replay-from DIR" in res.stderr
    res = _bench("--methods", "lmpc-replay", "--replay-from", str(tmp_path),
                 "--replay-of", "mpc", "--out", str(tmp_path / "x"))
    assert res.returncode == 2
    assert "lmpc-replay needs --replay-from DIR" in res.stderr  # no decisions/ folder
    (tmp_path / "decisions").mkdir()
    res = _bench("--methods", "lmpc-replay", "--replay-from", str(tmp_path),
                 "--replay-of", "mpc", "--out", str(tmp_path / "x"))
    assert res.returncode == 2
    assert "--replay-of 'mpc'" in res.stderr


def test_a_scene_without_a_recorded_log_gets_an_error_row_naming_the_file(
        tmp_path: Path) -> None:
    (tmp_path / "rec" / "decisions").mkdir(parents=True)
    res = _bench("--methods", "lmpc-replay", "--replay-from", str(tmp_path / "rec"),
                 "--out", str(tmp_path / "rep"))
    # its only row is an error: the run says so with its exit code (issue 21)
    assert res.returncode == 1, res.stderr[-2000:]
    assert "every one of the 1 scene(s) ended in an error" in res.stderr
    csv_text = (tmp_path / "rep" / "results.csv").read_text()
    assert "usi,0,lmpc-replay,error" in csv_text
    assert "no recorded decision log" in csv_text and "usi-000-lmpc-local.jsonl" in csv_text
    assert "usi seed 0: not checked" in (tmp_path / "rep" / "replay_check.txt").read_text()


def test_replay_check_calls_a_repeat_only_with_every_prompt_found_and_the_same_row() -> None:
    from lmpc_bridge.evaluation.replay import replay_check

    recorded = [{"family": "eoa", "seed": s, "method": "lmpc-local", "outcome": "reached",
                 "time_s": 120.0, "overall_cost": 244.6886} for s in range(5)]

    def replayed(seed: int, *, unmatched: int = 0, oc: float = 244.6886,
                 time_s: float = 120.0, outcome: str = "reached") -> dict:
        return {"family": "eoa", "seed": seed, "method": "lmpc-replay", "outcome": outcome,
                "time_s": time_s, "overall_cost": oc, "replay_unmatched": unmatched,
                "replay_answered": 40, "detail": ""}

    rows = [replayed(0, oc=244.6887),           # last rounded digit: still a repeat
            replayed(1, unmatched=1),           # a prompt the log never saw
            replayed(2, oc=244.7),              # another cost
            replayed(3, time_s=120.1),          # another time
            replayed(4, outcome="collision")]
    lines = replay_check(rows, recorded, "lmpc-local")
    verdicts = [line.split(": ")[1] for line in lines]
    assert verdicts == ["exact repeat", "differs", "differs", "differs", "differs"], lines
    assert replay_check(rows[:1], recorded, "lmpc-rules")[0].endswith(
        "no recorded lmpc-rules row to compare with")
