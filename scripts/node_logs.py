"""What a node's log says went wrong (``run_graph.py``'s summary of a run that ended in an
error): the first error line of a log, and "node NAME stopped early (...)"."""
from __future__ import annotations

import subprocess
from pathlib import Path
from typing import Optional, Protocol, Sequence


class NodeProcess(Protocol):
    """A started node as ``run_graph.Child`` has it: its name, its process and the recent
    lines of its output."""

    @property
    def name(self) -> str: ...

    @property
    def proc(self) -> subprocess.Popen[str]: ...

    @property
    def lines(self) -> Sequence[str]: ...


def first_error_line(lines: Sequence[str]) -> Optional[str]:
    """The first error a node's log shows, as one line: a ``scene error:`` line, else the
    exception line of the first Python traceback (with up to two lines of its message,
    e.g. pydantic's field and reason), else the first ``[ERROR]`` / ``[FATAL]`` log line."""
    for line in lines:
        if line.startswith("scene error:"):
            return line.strip()
    for i, line in enumerate(lines):
        if not line.startswith("Traceback"):
            continue
        for j in range(i + 1, len(lines)):
            if lines[j] and not lines[j].startswith(" "):
                parts = [lines[j].strip()]
                for more in lines[j + 1:j + 3]:
                    if not more.strip() or more.startswith(("Traceback", "During handling",
                                                            "The above exception", "[")):
                        break
                    parts.append(more.strip())
                return " ".join(parts)[:600]
        break
    for line in lines:
        if line.startswith(("[ERROR]", "[FATAL]")):
            return line.strip()[:600]
    return None


def log_lines(run_dir: Path, child: Optional[NodeProcess]) -> list[str]:
    """All lines of a node's log file (``Child.lines`` keeps only the recent ones)."""
    if child is None:
        return []
    try:
        return (run_dir / f"{child.name}.log").read_text(errors="replace").splitlines()
    except OSError:
        return list(child.lines)


def stopped_early(run_dir: Path, children: Sequence[NodeProcess], name: str) -> str:
    """"node NAME stopped early", with the first error its log shows (the bridge's is
    reported on its own by ``run_graph.summarize``)."""
    child = next((c for c in children if c.name == name), None)
    error = None
    if name != "bridge" and child is not None:
        lines = log_lines(run_dir, child)
        error = first_error_line(lines)
        code = child.proc.returncode
        if error is None and code is not None and code > 0:
            # a node that exits with a message of its own (no traceback): its last line
            error = next((ln.strip()[:600] for ln in reversed(lines) if ln.strip()), None)
    return f"node {name} stopped early" + (f" ({error})" if error else "")
