"""Training through the Gymnasium bridge on a lossy link: does it finish, how long do outages cost?

A lockstep simulator on host A, ``train --backend ros`` on host B, the hosts joined through
ops_bench.relay (ops_bench.hosts.RelayedHosts; this kernel has no netem). Phases, each
``--steps`` training steps long (the run's step counter, read from its progress line):

- clean link, then ``--loss`` of the frames lost each way;
- an outage of ``--outage-s`` seconds (the link drops everything), then a clean link: the time
  from the link's return to the next step counted (``back after``);
- stuck links (the relay's ``"stuck"``: the DDS links open then stay dead, discovery goes on),
  left on until the run logs that the simulator answered again: the time that took, which only
  the bridge's replacing its DDS participant ends (``reconnect_after_s``, 30 s by default;
  docs/interfaces.md, "A process frozen"). The progress bar cannot tell: it is drawn late, and
  a count drawn during the fault may be one reached before it.

Prints steps/s per phase, the outage's recovery and whether training finished with exit 0, and
rewrites the "Training through faults" section of docs/benchmarks.md. Needs root and `ip`.
Usage (after `source setup.bash`, as root):
ops-bench bridge-faults [--stage 5] [--mode hard] [--steps 1000] [--loss 0.2]
[--outage-s 30]
"""

from __future__ import annotations

import argparse
import platform
import re
import sys
import tempfile
import time
from pathlib import Path

SECTION = "## Training through faults"
ANSWERED = "the simulator answered again"  # the bridge's log line after an outage
REPLACED = "replacing this bridge's DDS participant"


def steps_done(proc, total: int) -> int:
    """The latest step count of train's progress bar (``N/TOTAL``)."""
    found = re.findall(rf"\b(\d+)/{total}\b", proc.output)
    return int(found[-1]) if found else 0


def wait_steps(proc, total: int, target: int, timeout: float) -> float:
    """Until the run has done ``target`` steps; returns the time it took."""
    t0 = time.monotonic()
    while steps_done(proc, total) < target:
        if proc.popen.poll() is not None:
            raise RuntimeError(f"train exited ({proc.popen.returncode}):\n{proc.output[-3000:]}")
        if time.monotonic() - t0 > timeout:
            raise RuntimeError(f"no {target} steps within {timeout:g} s:\n{proc.output[-3000:]}")
        time.sleep(0.05)
    return time.monotonic() - t0


def stuck_links(hosts, proc, timeout: float = 600.0) -> dict:
    """The relay's stuck links, on until the run logs an answer again: how long that took and
    how many times the bridge replaced its participant meanwhile."""
    answered = proc.output.count(ANSWERED)
    replaced = proc.output.count(REPLACED)
    hosts.set(stuck=True)
    hosts.relay.wait_for("STUCK", timeout=10)
    t0 = time.monotonic()
    try:
        proc.wait_for(re.escape(ANSWERED), timeout=timeout, count=answered + 1)
    finally:
        hosts.set()
    took = time.monotonic() - t0
    return {"answered_after_s": took, "replacements": proc.output.count(REPLACED) - replaced}


def run(args, tmp: Path) -> dict:
    from ops_bench.hosts import RelayedHosts
    from ops_bench.processes import ProcessGroup, executable, sim_command

    rows: dict = {}
    with RelayedHosts(tmp, seed=2) as hosts:
        group = ProcessGroup(tmp)
        try:
            env = hosts.env()
            sim = sim_command(
                f"stage:={args.stage}", f"mode:={args.mode}", "seed:=5", "lockstep:=true"
            )
            hosts.a.start(group, sim, name="sim", env=env).wait_for("stage=", timeout=120)
            total = 4 * args.steps
            train = [*executable("ops_gym_bridge", "train"), "--backend", "ros"]
            train += ["--algo", "sac", "--stage", str(args.stage), "--mode", args.mode]
            train += ["--timesteps", str(total), "--out", str(tmp / "model")]
            train += ["--hyperparams", "learning_starts=200", "train_freq=8", "gradient_steps=1"]
            proc = hosts.b.start(group, train, name="train", env=env)
            proc.wait_for(r"\[train\] training started", timeout=180)
            wait_steps(proc, total, 100, 180)  # discovery done, steps flowing

            def phase(label: str, loss: float = 0.0) -> None:
                hosts.set(loss=loss)
                start = steps_done(proc, total)
                took = wait_steps(proc, total, start + args.steps, 600)
                rows[label] = {"steps_per_s": args.steps / took}
                print(f"[bench] {label}: {rows[label]}", flush=True)

            phase("clean")
            phase(f"loss {100 * args.loss:g} % each way", loss=args.loss)
            hosts.set(down=True)
            time.sleep(args.outage_s)
            seen = steps_done(proc, total)
            hosts.set()
            back = wait_steps(proc, total, seen + 1, 600)
            rows[f"outage {args.outage_s:g} s"] = {"back_s": back}
            print(f"[bench] outage: back after {back:.2f} s", flush=True)
            wait_steps(proc, total, steps_done(proc, total) + 50, 600)  # flowing again
            rows["stuck links"] = stuck_links(hosts, proc)
            print(f"[bench] stuck links: {rows['stuck links']}", flush=True)
            code = proc.wait_exit(1800)
            rows["finished"] = {"exit": code, "answered_again": ANSWERED in proc.output}
            print(f"[bench] train exited {code}", flush=True)
        finally:
            group.stop_all()
    return rows


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--stage", type=int, default=5)
    parser.add_argument("--mode", default="hard")
    parser.add_argument("--steps", type=int, default=1000, help="training steps per phase")
    parser.add_argument("--loss", type=float, default=0.2, help="frames lost each way")
    parser.add_argument("--outage-s", type=float, default=30.0)
    parser.add_argument("--no-docs", action="store_true")
    args = parser.parse_args(argv)
    from ops_bench.docs import write_section
    from ops_bench.hosts import netns_unavailable_reason

    reason = netns_unavailable_reason()
    if reason:
        print(f"bench_bridge_faults: {reason}", file=sys.stderr)
        return 1
    tmp = Path(tempfile.mkdtemp(prefix="bench_bridge_faults_"))
    rows = run(args, tmp)
    lines = ["| condition | figure |", "|---|---|"]
    for label, row in rows.items():
        if "steps_per_s" in row:
            lines.append(f"| {label} | {row['steps_per_s']:.1f} training steps/s |")
        elif "back_s" in row:
            lines.append(f"| {label} | next step {row['back_s']:.2f} s after the link returned |")
        elif "answered_after_s" in row:
            lines.append(
                f"| {label} | answered again {row['answered_after_s']:.1f} s after they stuck, "
                f"the fault still on ({row['replacements']} DDS participant(s) replaced) |"
            )
    done = rows.get("finished", {})
    cmd = "ops-bench bridge-faults " + " ".join(sys.argv[1:])
    section = (
        f"{SECTION}\n\n`train --backend ros` (SAC, default `--ros-timeout 0`: no deadline) on "
        f"host B against a lockstep stage {args.stage} {args.mode} simulator on host A through "
        f"ops_bench.relay, {args.steps} training steps per condition. Command: "
        f"`{cmd.strip()}` ({platform.node()}, {time.strftime('%Y-%m-%d')}, one run; the "
        "machine's other jobs load it too).\n\n" + "\n".join(lines) + "\n\n"
        f"The run finished with exit code {done.get('exit')} "
        f"({'it logged that the simulator answered again' if done.get('answered_again') else ''})."
        f" Logs: {tmp}.\n"
    )
    print(section)
    if not args.no_docs:
        write_section(SECTION, section)
    return 0 if done.get("exit") == 0 else 1


if __name__ == "__main__":
    raise SystemExit(main())
