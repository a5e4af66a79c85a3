"""The benchmark's whole smoke profile on a two-node Ray cluster: the head (1 CPU) in network
namespace A, a worker node (1 CPU) in namespace B with nothing of the project on its path, token
authentication on (ops_bench.ray_cluster builds it; docs/cluster.md does the same on real machines).

Prints the figures (wall time, runs per node, retries, the runs' own time) and rewrites the
"Measured" section of docs/cluster.md. Run as root, after `source setup.bash`:

    ops-bench ray-cluster
"""

from __future__ import annotations

import argparse
import json
import os
import re
import sys
import tempfile
import time
from pathlib import Path

from ops_bench import REPO
from ops_bench.hosts import TwoHosts, netns_unavailable_reason
from ops_bench.processes import ProcessGroup
from ops_bench.ray_cluster import RayCluster

DOC = REPO / "docs" / "cluster.md"
BEGIN, END = "<!-- bench_ray_cluster: begin -->", "<!-- bench_ray_cluster: end -->"
COMMAND = "ops-bench ray-cluster"


def measure(root: Path, profile: str) -> dict:
    group = ProcessGroup(root)
    with TwoHosts() as hosts:
        cluster = RayCluster(hosts, group, root / "cluster")
        try:
            cluster.start_head()
            cluster.start_worker()
            importable = cluster.project_importable_on_worker()
            out = root / "out"
            cmd = ["env", "-C", str(root), sys.executable, "-m", "ops_experiments.table1.benchmark"]
            cmd += ["--profile", profile]
            cmd += ["--out", str(out), "--ray-address", cluster.address, "--status-every", "60"]
            t0 = time.monotonic()
            bench = hosts.a.start(group, cmd, name="benchmark", env=cluster.driver_env())
            code = bench.wait_exit(3600)
            wall = time.monotonic() - t0
            text = bench.output
        finally:
            group.stop_all()
            hosts.close()  # every Ray process of both nodes
            cluster.close()
    runs, per_node, run_s = 0, {}, 0.0
    for rec_path in sorted(out.glob("runs/*/run.json")):
        rec = json.loads(rec_path.read_text())
        runs += 1
        run_s += float(rec["wall_s"])
        log = (out / "logs" / f"{rec_path.parent.name}.log").read_text()
        node = re.findall(r"attempt on node (\S+)", log)[-1]
        per_node[node] = per_node.get(node, 0) + 1
    planned = re.search(r"(\d+) runs in the plan", text)
    return {
        "exit": code,
        "planned": int(planned.group(1)) if planned else None,
        "stored": runs,
        "per_node": dict(sorted(per_node.items())),
        "retries": len(re.findall(r"retry \d+/\d+", text)),
        "ray_errors": len(re.findall(r": Ray error on node", text)),
        "wall_s": round(wall, 1),
        "runs_s": round(run_s, 1),
        "project_on_worker": importable,
        "load": os.getloadavg()[0],
        "profile": profile,
    }


def section(r: dict) -> str:
    nodes = ", ".join(f"{n}: {k}" for n, k in r["per_node"].items())
    return "\n".join(
        [
            BEGIN,
            f"Measured with `{COMMAND}` (as root, on this 2-core machine: head and worker node "
            f"1 CPU each; 1-minute load average {r['load']:.1f} at the end, other jobs share "
            "the machine):",
            "",
            "| smoke profile on two nodes | figure |",
            "|---|---|",
            f"| runs stored / planned | {r['stored']} / {r['planned']} (exit {r['exit']}) |",
            f"| runs per node (where each finished) | {nodes} |",
            f"| Ray errors, retries | {r['ray_errors']}, {r['retries']} |",
            f"| wall time of the benchmark | {r['wall_s']:.0f} s |",
            f"| sum of the runs' own wall times | {r['runs_s']:.0f} s |",
            "| project importable on the worker node (ops_gym_bridge, ops_sim_ros, "
            f"ops_controller_ros) | {r['project_on_worker']} |",
            END,
        ]
    )


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--profile", default="smoke", choices=("smoke",))
    p.add_argument("--no-doc", action="store_true", help="print only; leave docs/ alone")
    args = p.parse_args(argv)
    reason = netns_unavailable_reason()
    if reason:
        print(f"bench_ray_cluster: {reason}", file=sys.stderr)
        return 2
    with tempfile.TemporaryDirectory(prefix="bench_ray_") as tmp:
        r = measure(Path(tmp), args.profile)
    print(json.dumps(r, indent=1))
    text = section(r)
    print(text)
    if not args.no_doc:
        doc = DOC.read_text()
        if BEGIN in doc and END in doc:
            doc = doc[: doc.index(BEGIN)] + text + doc[doc.index(END) + len(END) :]
            DOC.write_text(doc)
            print(f"updated {DOC.relative_to(REPO)}")
        else:
            print(f"{DOC.relative_to(REPO)} has no {BEGIN} section: not updated", file=sys.stderr)
    return 0 if r["exit"] == 0 and r["stored"] == r["planned"] else 1


if __name__ == "__main__":
    sys.exit(main())
