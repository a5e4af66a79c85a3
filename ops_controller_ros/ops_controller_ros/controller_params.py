"""Parameters every controller node declares, with one meaning across them."""

from ops_contract.node_params import ParamSpec

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
RIG_CONFIG = ParamSpec(
    "rig_config",
    "",
    "rig YAML (docs/rig.md): every controller keeps its set-points inside the lines' range "
    "it gives, moving them whole optical cycles inwards near a limit; the tracker also takes "
    "its optics.* and stage (parameters given explicitly override them) ('' : none)",
)
