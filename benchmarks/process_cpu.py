"""CPU s of every process one command starts, its orphans included (a local Dask cluster's forkserver and workers).

    python -m benchmarks.process_cpu -- python -m ftstab_mj sweep SWEEP.toml --out DIR --engine dask --workers 2

Linux only. This process becomes the reaper of the command's orphans (PR_SET_CHILD_SUBREAPER), polls
/proc every 10 ms for every descendant's own CPU (utime + stime, its children's not included), and
prints one line per process: pid, parent, CPU s, and what it is ("command", "forkserver", "worker"
for a child of a forkserver, else its command line). A process that lives less than 10 ms may be missed.
"""

import ctypes
import os
import subprocess
import sys
import time


def snapshot(root: int, seen: dict) -> None:
    """Update ``seen`` {pid: [ppid, CPU s, cmdline]} with the descendants of ``root`` (and of this process)."""
    tick = os.sysconf("SC_CLK_TCK")
    for entry in os.listdir("/proc"):
        if not entry.isdigit():
            continue
        try:
            with open(f"/proc/{entry}/stat") as f:
                fields = f.read().rsplit(")", 1)[1].split()
            with open(f"/proc/{entry}/cmdline", "rb") as f:
                cmd = f.read().replace(b"\0", b" ").decode(errors="replace").strip()
        except OSError:
            continue
        pid, ppid = int(entry), int(fields[1])
        if pid == root or pid in seen or ppid in seen or ppid == os.getpid():
            if pid != os.getpid():
                seen[pid] = [ppid, (int(fields[11]) + int(fields[12])) / tick, seen.get(pid, [0, 0, cmd])[2] or cmd]


def main():
    argv = sys.argv[1:]
    if argv[:1] == ["--"]:
        argv = argv[1:]
    if not argv or not sys.platform.startswith("linux"):
        sys.exit(__doc__)
    ctypes.CDLL(None, use_errno=True).prctl(36, 1, 0, 0, 0)  # PR_SET_CHILD_SUBREAPER
    proc = subprocess.Popen(argv, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    seen: dict = {}
    while proc.poll() is None:
        snapshot(proc.pid, seen)
        time.sleep(0.01)
    while True:  # the orphans, until they have all exited
        snapshot(proc.pid, seen)
        alive = [p for p in seen if os.path.exists(f"/proc/{p}") and p != proc.pid]
        try:
            while os.waitpid(-1, os.WNOHANG)[0]:
                pass
        except ChildProcessError:
            pass
        if not alive:
            break
        time.sleep(0.01)
    forkservers = {p for p in seen if "forkserver import main" in seen[p][2] and seen[p][0] not in
                   {q for q in seen if "forkserver import main" in seen[q][2]}}
    total = 0.0
    for pid, (ppid, cpu, cmd) in sorted(seen.items()):
        role = ("command" if pid == proc.pid else "forkserver" if pid in forkservers else
                "worker" if ppid in forkservers else cmd[:70])
        total += cpu
        print(f"{pid:>8} {ppid:>8} {cpu:7.2f} s  {role}")
    print(f"{'':>17} {total:7.2f} s  in all (load {os.getloadavg()[0]:.2f} at the end; exit {proc.returncode})")


if __name__ == "__main__":
    main()
