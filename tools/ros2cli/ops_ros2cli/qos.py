"""QoS options of ``ros2 topic echo`` / ``pub`` (same names and defaults as ros2topic)."""

PROFILE_KEYS = (
    "unknown",
    "system_default",
    "sensor_data",
    "services_default",
    "parameters",
    "parameter_events",
    "action_status_default",
    "best_available",
    "default",
)


def add_qos_arguments(parser, entity_type, default_profile):
    parser.add_argument(
        "--qos-profile",
        choices=PROFILE_KEYS,
        default=default_profile,
        help=f"Quality of service preset profile to {entity_type} with "
        f"(default: {default_profile})",
    )
    parser.add_argument(
        "--qos-depth",
        metavar="N",
        type=int,
        default=None,
        help=f"Queue size setting to {entity_type} with "
        "(overrides depth value of --qos-profile option)",
    )
    parser.add_argument(
        "--qos-history",
        choices=("system_default", "keep_last", "keep_all", "unknown"),
        default=None,
        help=f"History of samples setting to {entity_type} with "
        "(overrides history value of --qos-profile option)",
    )
    parser.add_argument(
        "--qos-reliability",
        choices=("system_default", "reliable", "best_effort", "unknown", "best_available"),
        default=None,
        help=f"Quality of service reliability setting to {entity_type} with "
        "(overrides reliability value of --qos-profile option)",
    )
    parser.add_argument(
        "--qos-durability",
        choices=("system_default", "transient_local", "volatile", "unknown", "best_available"),
        default=None,
        help=f"Quality of service durability setting to {entity_type} with "
        "(overrides durability value of --qos-profile option)",
    )


def qos_overridden(args):
    return any(
        getattr(args, name) is not None
        for name in ("qos_depth", "qos_history", "qos_reliability", "qos_durability")
    )


def profile_from_args(args):
    from rclpy.qos import (
        QoSDurabilityPolicy,
        QoSHistoryPolicy,
        QoSPresetProfiles,
        QoSProfile,
        QoSReliabilityPolicy,
    )

    base = QoSPresetProfiles.get_from_short_key(args.qos_profile)
    profile = QoSProfile(
        history=base.history,
        depth=base.depth,
        reliability=base.reliability,
        durability=base.durability,
        lifespan=base.lifespan,
        deadline=base.deadline,
        liveliness=base.liveliness,
        liveliness_lease_duration=base.liveliness_lease_duration,
    )
    if args.qos_reliability is not None:
        profile.reliability = QoSReliabilityPolicy.get_from_short_key(args.qos_reliability)
    if args.qos_durability is not None:
        profile.durability = QoSDurabilityPolicy.get_from_short_key(args.qos_durability)
    if args.qos_history is not None:
        profile.history = QoSHistoryPolicy.get_from_short_key(args.qos_history)
    if args.qos_depth is not None and args.qos_depth >= 0:
        profile.depth = args.qos_depth
    if profile.history == QoSHistoryPolicy.KEEP_LAST and profile.depth == 0:
        profile.depth = 1
    return profile


def adapt_to_publishers(node, topic_name, profile):
    """Like ``ros2 topic echo``: reliable / transient_local when all publishers offer it."""
    from rclpy.qos import QoSDurabilityPolicy, QoSReliabilityPolicy

    infos = node.get_publishers_info_by_topic(topic_name)
    if not infos:
        return profile
    reliable = sum(1 for i in infos if i.qos_profile.reliability == QoSReliabilityPolicy.RELIABLE)
    transient = sum(
        1 for i in infos if i.qos_profile.durability == QoSDurabilityPolicy.TRANSIENT_LOCAL
    )
    if reliable == len(infos):
        profile.reliability = QoSReliabilityPolicy.RELIABLE
    else:
        if reliable:
            print(
                "Some, but not all, publishers are offering "
                "QoSReliabilityPolicy.RELIABLE. Falling back to "
                "QoSReliabilityPolicy.BEST_EFFORT as it will connect "
                "to all publishers"
            )
        profile.reliability = QoSReliabilityPolicy.BEST_EFFORT
    if transient == len(infos):
        profile.durability = QoSDurabilityPolicy.TRANSIENT_LOCAL
    else:
        if transient:
            print(
                "Some, but not all, publishers are offering "
                "QoSDurabilityPolicy.TRANSIENT_LOCAL. Falling back to "
                "QoSDurabilityPolicy.VOLATILE as it will connect "
                "to all publishers"
            )
        profile.durability = QoSDurabilityPolicy.VOLATILE
    return profile
