"""Parameters every controller node declares, with one meaning across them."""

from ops_sim_ros.node_params import ParamSpec

TIMEOUT = ParamSpec(
    "timeout_s",
    1.0,
    "re-send a command unanswered for this long",
    low=0.01,
    high=3600.0,
)
LOG_PERIOD = ParamSpec(
    "log_period_s",
    1.0,
    "period of the progress log line",
    low=0.1,
    high=3600.0,
)
