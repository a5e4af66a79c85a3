"""A lossy Ethernet link in software: forwards every frame between two interfaces, dropping,
delaying or cutting them as told (this kernel has no netem).

Run inside the namespace that holds both interfaces (ops_bench.hosts.RelayedHosts builds it:
host A <-veth-> [relay namespace] <-veth-> host B); it reads and writes whole frames with
AF_PACKET sockets, so the hosts see one Ethernet segment (ARP, multicast discovery and UDP alike)
and DDS between them is not changed in any other way.

The conditions come from a JSON control file, re-read whenever it changes (``{"loss": 0.05,
"delay_ms": 20, "down": false, "stuck": false}``; loss per frame and per direction, a fixed
one-way delay, an outage that drops everything, and stuck links), so a test or a benchmark
changes them while the link runs. Counts of forwarded and dropped frames are printed every
``--report-s`` seconds and on exit.

Stuck links (``"stuck": true``) stand for DDS state that a frozen process left unable to carry
messages: every flow of DDS user traffic (UDP to a port of the RTPS user-traffic mapping, keyed by
addresses and ports both ways) that crossed the link before it turned on is dropped until it
turns off, while discovery (the metatraffic ports) and flows new since then pass. The endpoints
stay matched and nothing arrives; a participant opened anew gets new flows
(docs/interfaces.md, "A process frozen").

Usage: ip netns exec R python -m ops_bench.relay IFACE_A IFACE_B --control FILE [--seed 0]
"""

from __future__ import annotations

import argparse
import heapq
import json
import os
import random
import select
import signal
import socket
import sys
import time

ETH_P_ALL = 0x0003
PACKET_OUTGOING = 4  # a frame this host sent: not to be forwarded again
MAX_FRAME = 65536
#: The RTPS port mapping (DDSI-RTPS 9.6.1.1): PB + DG * domain + offset, user traffic at
#: offset d2 = 1 (multicast) and d3 + PG * participant = 11, 13, 15, ... (unicast).
RTPS_PORT_BASE, RTPS_DOMAIN_GAIN = 7400, 250


class Conditions:
    """The control file's figures, re-read when the file changes."""

    def __init__(self, path: str):
        self.path = path
        self.loss = 0.0
        self.delay_s = 0.0
        self.down = False
        self.stuck = False
        self._stamp = None
        self.reload()

    def reload(self) -> None:
        try:
            stat = os.stat(self.path)
        except FileNotFoundError:
            return
        stamp = (stat.st_mtime_ns, stat.st_size)
        if stamp == self._stamp:
            return
        try:
            with open(self.path) as f:
                data = json.load(f)
        except (OSError, ValueError):
            return  # half-written: the next look gets it
        self._stamp = stamp
        self.loss = min(max(float(data.get("loss", 0.0)), 0.0), 1.0)
        self.delay_s = max(float(data.get("delay_ms", 0.0)), 0.0) / 1000.0
        self.down = bool(data.get("down", False))
        self.stuck = bool(data.get("stuck", False))
        print(
            f"[relay] loss {self.loss:.3f} delay {self.delay_s * 1000:.1f} ms "
            f"{'DOWN' if self.down else 'up'}{' STUCK' if self.stuck else ''}",
            flush=True,
        )


def is_user_port(port: int) -> bool:
    """Whether ``port`` carries DDS user traffic in the RTPS port mapping (any domain)."""
    if port < RTPS_PORT_BASE:
        return False
    offset = (port - RTPS_PORT_BASE) % RTPS_DOMAIN_GAIN
    return offset == 1 or (offset >= 11 and offset % 2 == 1)


def udp_header_at(frame: bytes) -> int | None:
    """Where the UDP header of an IPv4 / UDP frame starts (its 8 bytes all there), else None
    (not IPv4 / UDP, or a later fragment: no UDP header in it)."""
    if len(frame) < 34 or frame[12:14] != b"\x08\x00" or frame[23] != 17:
        return None
    if int.from_bytes(frame[20:22], "big") & 0x1FFF:
        return None
    at = 14 + (frame[14] & 0x0F) * 4
    return at if len(frame) >= at + 8 else None


def user_flow(frame: bytes) -> tuple | None:
    """(source address, source port, destination address, destination port) of an IPv4 / UDP
    frame to a DDS user-traffic port, else None."""
    at = udp_header_at(frame)
    if at is None:
        return None
    source, destination = (int.from_bytes(frame[k : k + 2], "big") for k in (at, at + 2))
    if not is_user_port(destination):
        return None
    return (frame[26:30], source, frame[30:34], destination)


def without_udp_checksum(frame: bytes) -> bytes:
    """The frame with its UDP checksum cleared (0: "none", allowed in IPv4).

    A veth hands a locally sent datagram over with its checksum left to the "hardware"
    (offload); forwarded as captured it would be dropped as corrupt on the other side."""
    at = udp_header_at(frame)
    if at is None:
        return frame
    return frame[: at + 6] + b"\x00\x00" + frame[at + 8 :]


def open_port(name: str) -> socket.socket:
    sock = socket.socket(socket.AF_PACKET, socket.SOCK_RAW, socket.htons(ETH_P_ALL))
    sock.bind((name, 0))
    sock.setblocking(False)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4 << 20)
    return sock


def run(ports: list[str], control: str, seed: int, report_s: float) -> dict:
    rng = random.Random(seed)
    cond = Conditions(control)
    socks = [open_port(p) for p in ports]
    peer = {socks[0].fileno(): socks[1], socks[1].fileno(): socks[0]}
    queue: list[tuple[float, int, socket.socket, bytes]] = []  # (due, n, out, frame)
    counts = {"forwarded": 0, "dropped": 0, "stuck": 0}
    flows: set = set()  # DDS user-traffic flows seen so far
    blocked: set | None = None  # ... those that crossed before the links stuck (while they are)
    n = 0
    stop = []
    for signum in (signal.SIGINT, signal.SIGTERM):
        signal.signal(signum, lambda s, f: stop.append(s))
    next_look = next_report = time.monotonic()
    while not stop:
        now = time.monotonic()
        if now >= next_look:
            cond.reload()
            if not cond.stuck:
                blocked = None
            elif blocked is None:  # just stuck: the flows seen so far, and no later ones
                blocked = set(flows)
            next_look = now + 0.1
        if now >= next_report:
            print(f"[relay] {counts}", flush=True)
            next_report = now + report_s
        wait = 0.05 if not queue else max(0.0, min(0.05, queue[0][0] - now))
        try:
            ready, _, _ = select.select(socks, [], [], wait)
        except InterruptedError:
            continue
        for sock in ready:
            while True:
                try:
                    frame, addr = sock.recvfrom(MAX_FRAME)
                except BlockingIOError:
                    break
                if addr[2] == PACKET_OUTGOING:
                    continue
                if cond.down or (cond.loss and rng.random() < cond.loss):
                    counts["dropped"] += 1
                    continue
                flow = user_flow(frame)
                if flow is not None:
                    if blocked is not None and flow in blocked:
                        counts["stuck"] += 1
                        continue
                    flows.add(flow)
                n += 1
                due = time.monotonic() + cond.delay_s
                out = peer[sock.fileno()]
                heapq.heappush(queue, (due, n, out, without_udp_checksum(frame)))
        now = time.monotonic()
        while queue and queue[0][0] <= now:
            _, _, out, frame = heapq.heappop(queue)
            try:
                out.send(frame)
                counts["forwarded"] += 1
            except OSError:
                counts["dropped"] += 1
    print(f"[relay] stopped: {counts}", flush=True)
    return counts


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("ports", nargs=2, metavar="IFACE", help="the two interfaces to join")
    parser.add_argument("--control", required=True, help="JSON file of loss, delay_ms, down, stuck")
    parser.add_argument("--seed", type=int, default=0, help="seed of the loss draws")
    parser.add_argument("--report-s", type=float, default=10.0, help="period of the counts line")
    args = parser.parse_args(argv)
    try:
        run(args.ports, args.control, args.seed, args.report_s)
    except OSError as exc:
        print(f"[relay] error: {exc}", file=sys.stderr, flush=True)
        return 1
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
