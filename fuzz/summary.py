"""Summarise a campaign log of scripts/fuzz.sh: executions (summed over the restarts after
findings), the last coverage (libFuzzer's cov: and ft:), corpus size and findings.

    python fuzz/summary.py fuzz/work/logs/ply.log [fuzz/work/crashes/ply]
"""
import re
import sys
from pathlib import Path

PROGRESS = re.compile(r"^#(\d+)\s+\w+\s+cov: (\d+) ft: (\d+) corp: (\d+)/(\S+)(?:.*?exec/s: (\d+))?")


def summarise(log, crashes=None) -> dict:
    runs, last, best = [], None, 0
    for line in Path(log).read_text(errors="replace").splitlines():
        if line.startswith("INFO: Seed:"):
            if best:
                runs.append(best)
            best = 0
        m = PROGRESS.match(line)
        if m:
            best = max(best, int(m.group(1)))
            last = m
        d = re.match(r"^Done (\d+) runs", line)
        if d:
            best = max(best, int(d.group(1)))
    if best:
        runs.append(best)
    out = {"executions": sum(runs), "starts": len(runs)}
    if last:
        out.update(cov=int(last.group(2)), ft=int(last.group(3)), corpus=int(last.group(4)),
                   corpus_size=last.group(5))
    if crashes and Path(crashes).is_dir():
        out["findings"] = sorted(p.name for p in Path(crashes).iterdir()
                                 if p.name.startswith(("crash-", "timeout-", "oom-", "leak-")))
    return out


def table(work="fuzz/work", names=None) -> str:
    """A markdown table of every campaign log under `work`/logs."""
    rows = ["| target | executions | starts | cov | ft | corpus | findings saved |",
            "|---|---:|---:|---:|---:|---|---:|"]
    for log in sorted(Path(work, "logs").glob("*.log")):
        if names and log.stem not in names:
            continue
        s = summarise(log, Path(work, "crashes", log.stem))
        rows.append(f"| `{log.stem}` | {s['executions']:,} | {s['starts']} | {s.get('cov', '')} | "
                    f"{s.get('ft', '')} | {s.get('corpus', '')} ({s.get('corpus_size', '')}) | "
                    f"{len(s.get('findings', []))} |")
    return "\n".join(rows)


if __name__ == "__main__":
    if sys.argv[1:2] == ["--table"]:
        print(table(*sys.argv[2:3]))
        sys.exit()
    s = summarise(sys.argv[1], sys.argv[2] if len(sys.argv) > 2 else None)
    print(" ".join(f"{k}={v}" for k, v in s.items()))
