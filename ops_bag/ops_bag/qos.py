"""QoS profiles as rosbag2 (metadata version 9, ROS 2 Jazzy) records them: one mapping per
publisher, policies as lower-case names, durations as ``{sec, nsec}``."""

from __future__ import annotations

import yaml

INFINITE_NS = 2**63 - 1
_POLICIES = ("history", "reliability", "durability", "liveliness")


def _duration_dict(duration) -> dict:
    ns = int(getattr(duration, "nanoseconds", duration))
    if ns >= INFINITE_NS:
        ns = INFINITE_NS
    return {"sec": ns // 1_000_000_000, "nsec": ns % 1_000_000_000}


def _duration_ns(value) -> int:
    sec, nsec = int(value.get("sec", 0)), int(value.get("nsec", 0))
    ns = sec * 1_000_000_000 + nsec
    # Foxy-era "infinite" values (0x7FFFFFFF s) mean infinite too
    return INFINITE_NS if ns >= INFINITE_NS or sec >= 0x7FFFFFFF else ns


def to_dict(profile) -> dict:
    """An rclpy QoSProfile as a rosbag2 v9 mapping."""
    return {
        "history": profile.history.name.lower(),
        "depth": int(profile.depth),
        "reliability": profile.reliability.name.lower(),
        "durability": profile.durability.name.lower(),
        "deadline": _duration_dict(profile.deadline),
        "lifespan": _duration_dict(profile.lifespan),
        "liveliness": profile.liveliness.name.lower(),
        "liveliness_lease_duration": _duration_dict(profile.liveliness_lease_duration),
        "avoid_ros_namespace_conventions": bool(profile.avoid_ros_namespace_conventions),
    }


def dumps(profiles: list[dict]) -> str:
    """The YAML string of a list of profiles (MCAP channel metadata ``offered_qos_profiles``)."""
    return yaml.safe_dump(profiles, default_flow_style=False, sort_keys=False) if profiles else "[]"


def loads(value) -> list[dict]:
    """Profiles from metadata (a list, or a YAML string as older rosbag2 versions wrote)."""
    if not value:
        return []
    if isinstance(value, str):
        value = yaml.safe_load(value) or []
    return [dict(v) for v in value if isinstance(v, dict)]


def _policy(enum_cls, value, default):
    if isinstance(value, int):
        try:
            return enum_cls(value)
        except ValueError:
            return default
    try:
        return enum_cls[str(value).upper()]
    except KeyError:
        return default


def playback_profile(profiles: list[dict]):
    """The QoSProfile ``ros2 bag play`` offers for a topic recorded with ``profiles``.

    As rosbag2: the recorded reliability and durability when every recorded publisher offered
    the same, else reliable / volatile. History is keep-last; a transient-local (latched) topic
    keeps its last message only (depth 1), so a subscriber that joins late gets the latest value,
    as from the original publisher; other topics get depth 10 or the recorded depth if larger.
    """
    from rclpy.duration import Duration
    from rclpy.qos import (
        DurabilityPolicy,
        HistoryPolicy,
        LivelinessPolicy,
        QoSProfile,
        ReliabilityPolicy,
    )

    profile = QoSProfile(
        history=HistoryPolicy.KEEP_LAST,
        depth=10,
        reliability=ReliabilityPolicy.RELIABLE,
        durability=DurabilityPolicy.VOLATILE,
    )
    if not profiles:
        return profile
    keys = {
        (
            str(p.get("reliability")),
            str(p.get("durability")),
            str(p.get("liveliness")),
            _duration_ns(p.get("deadline", {})),
            _duration_ns(p.get("liveliness_lease_duration", {})),
        )
        for p in profiles
    }
    if len(keys) != 1:
        return profile
    first = profiles[0]
    profile.reliability = _policy(
        ReliabilityPolicy, first.get("reliability"), ReliabilityPolicy.RELIABLE
    )
    if profile.reliability not in (ReliabilityPolicy.RELIABLE, ReliabilityPolicy.BEST_EFFORT):
        profile.reliability = ReliabilityPolicy.RELIABLE
    profile.durability = _policy(
        DurabilityPolicy, first.get("durability"), DurabilityPolicy.VOLATILE
    )
    if profile.durability not in (DurabilityPolicy.VOLATILE, DurabilityPolicy.TRANSIENT_LOCAL):
        profile.durability = DurabilityPolicy.VOLATILE
    if profile.durability == DurabilityPolicy.TRANSIENT_LOCAL:
        profile.depth = 1
    else:
        profile.depth = max(10, max(int(p.get("depth", 0) or 0) for p in profiles))
    liveliness = _policy(LivelinessPolicy, first.get("liveliness"), LivelinessPolicy.AUTOMATIC)
    if liveliness in (LivelinessPolicy.AUTOMATIC, LivelinessPolicy.MANUAL_BY_TOPIC):
        profile.liveliness = liveliness
    for name in ("deadline", "lifespan", "liveliness_lease_duration"):
        ns = _duration_ns(first.get(name, {}))
        if 0 < ns < INFINITE_NS:
            setattr(profile, name, Duration(nanoseconds=ns))
    return profile


def describe(profile: dict) -> str:
    """One line per policy, for ``ros2 bag info`` and ``ros2 topic info -v``."""
    return ", ".join(f"{k}: {profile.get(k)}" for k in ("reliability", "durability", "history"))
